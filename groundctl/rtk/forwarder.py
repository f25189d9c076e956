"""The forwarder: corrections from a source to every vehicle, as GPS_RTCM_DATA.

An asyncio task owned by the flying command: it reads its source's chunks, frames
them (:class:`~groundctl.rtk.rtcm.RtcmFramer`), cuts each frame into
GPS_RTCM_DATA fragments (:class:`~groundctl.rtk.fragment.Fragmenter`) and sends
them to every vehicle heard (one copy each: every vehicle's stream has its own
sequence numbers).  It never blocks the control loop (UDP sends only), keeps to
``max_rate_Bps`` bytes of RTCM per second (a token bucket; frames over it are
dropped and counted), and keeps going when its source dies: one warning, then a
reconnect every ``retry_s`` seconds, the failures counted in the report.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import Clock
from groundctl.errors import GroundctlError, LinkError
from groundctl.link.fleet import FleetLink
from groundctl.record.events import EventSink
from groundctl.rtk.fragment import Fragmenter, TooLarge
from groundctl.rtk.rtcm import RtcmFramer
from groundctl.rtk.sources import RtkSource

log = logging.getLogger(__name__)


class RtkForwarder:
    """Forwards ``source`` to every vehicle on ``link``; :meth:`start`, :meth:`stop`."""

    def __init__(self, source: RtkSource, link: FleetLink, clock: Clock, *,
                 max_rate_Bps: float = 8000.0, retry_s: float = 2.0,
                 events: EventSink | None = None,
                 notify: Callable[[str], None] | None = None) -> None:
        if not max_rate_Bps > 0:
            raise ValueError(f"`max_rate_Bps` must be positive, got {max_rate_Bps}")
        self.source = source
        self.link = link
        self.clock = clock
        self.max_rate_Bps = max_rate_Bps
        self.retry_s = retry_s
        self.events = events
        self.notify = notify
        self.framer = RtcmFramer()
        self.fragmenter = Fragmenter()
        self.bytes_sent = 0
        """RTCM bytes forwarded (each message counted once, whatever the fleet's size)."""
        self.messages_sent = 0
        """RTCM messages forwarded."""
        self.packets_sent = 0
        """GPS_RTCM_DATA packets sent, every copy to every vehicle."""
        self.too_large = 0
        """Messages over the four fragments' 720 bytes, dropped."""
        self.rate_dropped = 0
        """Messages dropped to keep to ``max_rate_Bps``."""
        self.source_errors = 0
        """Times the source failed or ended (each followed by a retry)."""
        self.last_sent: dict[int, float] = {}
        """System id -> clock time corrections last went to it."""
        self.started_at: float | None = None
        self.stopped_at: float | None = None
        self._tokens = max_rate_Bps
        self._tokens_at: float | None = None
        self._task: asyncio.Task[None] | None = None

    # -- lifecycle ---------------------------------------------------------------------
    def start(self) -> None:
        self.started_at = self.clock.now()
        self._task = asyncio.create_task(self._run(), name="rtk-forwarder")

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._task
            self._task = None
        self.stopped_at = self.clock.now()

    async def _run(self) -> None:
        while True:
            try:
                async for chunk in self.source.chunks():
                    for frame in self.framer.feed(chunk):
                        self.forward(frame)
                why = "the source ended"
            except (GroundctlError, OSError, ValueError, asyncio.IncompleteReadError) as exc:
                why = str(exc)
            except Exception as exc:  # a source's own bug must not end the corrections
                log.exception("rtk source failed")
                why = f"{type(exc).__name__}: {exc}"
            self.source_errors += 1
            text = f"rtk: corrections stopped ({why}); retrying every {self.retry_s:g} s"
            if self.source_errors == 1 and self.notify is not None:
                self.notify(text)
            log.warning(text)
            if self.events is not None:
                self.events.emit("rtk_source_error", text=why, count=self.source_errors)
            await asyncio.sleep(max(self.clock.wall_interval(self.retry_s), 0.01))

    # -- one frame ---------------------------------------------------------------------
    def _allow(self, size: int, now: float) -> bool:
        if self._tokens_at is not None:
            self._tokens = min(self.max_rate_Bps,
                               self._tokens + (now - self._tokens_at) * self.max_rate_Bps)
        self._tokens_at = now
        if size > self._tokens:
            return False
        self._tokens -= size
        return True

    def forward(self, frame: bytes) -> None:
        """Send one RTCM3 frame to every vehicle heard (fire and forget)."""
        now = self.clock.now()
        try:
            fragments = self.fragmenter.split(frame)
        except TooLarge:
            self.too_large += 1
            return
        if not self._allow(len(frame), now):
            self.rate_dropped += 1
            return
        msgs = [mavlink.MAVLink_gps_rtcm_data_message(
            f.flags, len(f.data), f.data + bytes(180 - len(f.data))) for f in fragments]
        for sysid in list(self.link.vehicles):
            if self.link.address_of(sysid) is None:
                continue
            try:
                for msg in msgs:
                    self.link.send_message(sysid, msg)
            except LinkError:
                continue
            self.packets_sent += len(msgs)
            self.last_sent[sysid] = now
        self.bytes_sent += len(frame)
        self.messages_sent += 1

    # -- what the console and the report show ---------------------------------------------
    def age_of(self, sysid: int, now: float | None = None) -> float | None:
        """Seconds since corrections last went to ``sysid`` (None: never)."""
        at = self.last_sent.get(sysid)
        if at is None:
            return None
        return max(0.0, (self.clock.now() if now is None else now) - at)

    def summary(self, fixes: dict[int, int | None], now: float | None = None) -> str:
        """One fleet-wide phrase for the plain status line: ``rtk fixed 8/9 float 1/9 (3D:
        7), age <= 0.4 s``."""
        from groundctl.rtk.options import fix_name

        n = len(fixes)
        fixed = [s for s, f in fixes.items() if f == 6]
        floating = [s for s, f in fixes.items() if f == 5]
        other = sorted(s for s in fixes if s not in fixed and s not in floating)
        ages = [a for a in (self.age_of(s, now) for s in fixes) if a is not None]
        text = f"rtk fixed {len(fixed)}/{n} float {len(floating)}/{n}"
        if other:
            shown = ", ".join(f"{s} {fix_name(fixes[s])}" for s in other[:4])
            text += f" ({shown}{', ...' if len(other) > 4 else ''})"
        text += f", age <= {max(ages):.1f} s" if ages else ", nothing sent yet"
        return text

    def report(self) -> dict[str, Any]:
        """The report's ``rtk`` object."""
        end = self.stopped_at if self.stopped_at is not None else self.clock.now()
        span = end - self.started_at if self.started_at is not None else 0.0
        rate = self.bytes_sent * 8 / span if span > 0 else 0.0
        return {"source": self.source.spec.text, "kind": self.source.spec.kind,
                "bytes_sent": self.bytes_sent, "messages_sent": self.messages_sent,
                "rate_bps": round(rate, 1) if math.isfinite(rate) else None,
                "packets_sent": self.packets_sent, "bad_crc": self.framer.stats.bad_crc,
                "too_large": self.too_large, "rate_dropped": self.rate_dropped,
                "source_errors": self.source_errors, "file_loops": self.source.loops}
