"""TIMESYNC clock-offset estimation, without I/O.

We send ``tc1 = 0, ts1 = our time (ns)``; the vehicle answers ``tc1 = its
boot time (ns)`` and echoes ``ts1``.  Assuming a symmetric path, the vehicle
read its clock half-way through the round trip, so::

    offset = tc1 - (ts1 + now) / 2      (vehicle time = our time + offset)
    rtt    = now - ts1

Queueing delay only ever adds to one leg, so the samples with the smallest
RTT carry the least error: we keep a window of recent samples and report the
offset of the lowest-RTT one.  Answers to requests we did not make (PX4
broadcasts its replies; another GCS may be syncing too) are ignored.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from dataclasses import dataclass

NS = 1_000_000_000


@dataclass(frozen=True)
class TimesyncSample:
    """One answered request."""

    offset_ns: int
    """Vehicle clock minus our clock, in nanoseconds."""
    rtt_ns: int
    """Round-trip time of this exchange, in nanoseconds."""
    at: float
    """Our time (s) when the answer arrived."""


class TimesyncEstimator:
    """Offset of one vehicle's clock from ours, filtered over a window of samples."""

    def __init__(self, window: int = 16, max_pending: int = 32) -> None:
        if window < 1:
            raise ValueError(f"`window` must be at least 1, got {window}")
        self.samples: deque[TimesyncSample] = deque(maxlen=window)
        self._pending: OrderedDict[int, float] = OrderedDict()
        self._max_pending = max_pending
        self._last_ts1 = 0
        # (best, median rtt) of the window as it was, and which window that was: asked
        # for every vehicle every tick, changed once a second.
        self._cached: tuple[tuple[int, object, object], TimesyncSample | None,
                            float | None] | None = None

    def request(self, now: float) -> int:
        """The ``ts1`` (ns) to put in a request sent at ``now``; remembered as pending."""
        ts1 = round(now * NS)
        # Two requests in the same nanosecond (a manual clock) must stay distinct.
        ts1 = max(ts1, self._last_ts1 + 1)
        self._last_ts1 = ts1
        self._pending[ts1] = now
        while len(self._pending) > self._max_pending:
            self._pending.popitem(last=False)
        return ts1

    def receive(self, tc1: int, ts1: int, now: float) -> TimesyncSample | None:
        """Feed an answer; returns the sample, or None if it answers no request of ours."""
        if tc1 == 0 or self._pending.pop(ts1, None) is None:
            return None
        now_ns = round(now * NS)
        rtt = now_ns - ts1
        if rtt < 0:
            return None
        sample = TimesyncSample(offset_ns=tc1 - (ts1 + now_ns) // 2, rtt_ns=rtt, at=now)
        self.samples.append(sample)
        return sample

    def _window(self) -> tuple[TimesyncSample | None, float | None]:
        samples = self.samples
        # The window's ends themselves (held, so never confused with a new sample), not
        # their ids.
        key = (len(samples), samples[0], samples[-1]) if samples else (0, None, None)
        cached = self._cached
        if cached is not None and cached[0][0] == key[0] and cached[0][1] is key[1] \
                and cached[0][2] is key[2]:
            return cached[1], cached[2]
        best = min(samples, key=lambda s: s.rtt_ns, default=None)
        rtts = sorted(x.rtt_ns for x in samples)
        median = rtts[len(rtts) // 2] / NS if rtts else None
        self._cached = (key, best, median)
        return best, median

    @property
    def best(self) -> TimesyncSample | None:
        """The lowest-RTT sample in the window."""
        return self._window()[0]

    @property
    def median_rtt_s(self) -> float | None:
        """Median round trip over the window, s (None before the first answer)."""
        return self._window()[1]

    def recent_rtt_s(self, now: float, window_s: float = 10.0) -> float | None:
        """Median round trip of the samples answered in the last ``window_s`` seconds (None
        if there are none): what the link does now, not what it did before a freeze."""
        rtts = sorted(x.rtt_ns for x in self.samples if x.at >= now - window_s)
        return rtts[len(rtts) // 2] / NS if rtts else None

    @property
    def offset_s(self) -> float | None:
        """Vehicle time minus our time in seconds, or None before the first answer."""
        best = self.best
        return None if best is None else best.offset_ns / NS

    @property
    def rtt_s(self) -> float | None:
        """RTT of the most recent sample, in seconds."""
        return self.samples[-1].rtt_ns / NS if self.samples else None

    def vehicle_time_s(self, now: float) -> float | None:
        """The vehicle's boot-clock time (s) at our time ``now``, if known."""
        offset = self.offset_s
        return None if offset is None else now + offset


def answer(tc1: int, ts1: int, now: float) -> tuple[int, int] | None:
    """(tc1, ts1) answering a vehicle's request, or None if the message is not a request."""
    if tc1 != 0:
        return None
    return round(now * NS), ts1
