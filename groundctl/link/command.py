"""The COMMAND_LONG -> COMMAND_ACK exchange, with timeouts and retries, without I/O.

Written once in the h11 style: the exchange is told the time and what arrived,
and answers with what to send.  The async driver in
:mod:`groundctl.link.fleet` runs it over the socket; tests run it by hand.

Protocol rules (MAVLink command protocol):

* a resend carries ``confirmation`` incremented, so the vehicle can tell a
  retry from a new command (ArduPilot does not care, PX4 logs it);
* MAV_RESULT_IN_PROGRESS means the vehicle is working on it: do not resend
  (that could restart a long action), wait up to ``progress_timeout`` for
  the final ACK;
* ACCEPTED is success; anything else is a refusal, and the best explanation
  is the STATUSTEXT the vehicle sent around it ("Arm: Need Position
  Estimate"), which ArduPilot emits just before the ACK.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.errors import CommandRefused, CommandTimeout, LinkError
from groundctl.link.messages import command_long, command_name, result_name
from groundctl.vehicleid import sysid_of


class CommandExchange:
    """One command sent to one vehicle until it is ACKed, refused or given up."""

    def __init__(
        self,
        target_system: int,
        command: int,
        params: Sequence[float] = (),
        *,
        timeout: float = 1.0,
        attempts: int = 3,
        progress_timeout: float | None = None,
        reason_grace: float = 0.0,
        target_component: int = 1,
    ) -> None:
        if not timeout > 0:
            raise ValueError(f"`timeout` must be positive, got {timeout}")
        if attempts < 1:
            raise ValueError(f"`attempts` must be at least 1, got {attempts}")
        self.target_system = target_system
        self.target_component = target_component
        self.command = command
        self.params = tuple(float(p) for p in params)
        self.timeout = timeout
        self.attempts = attempts
        self.progress_timeout = 5 * timeout if progress_timeout is None else progress_timeout
        if reason_grace < 0:
            raise ValueError(f"`reason_grace` must be non-negative, got {reason_grace}")
        self.reason_grace = reason_grace
        self.name = command_name(command)

        self.sent = 0
        """How many times the command has gone out."""
        self.started_at: float | None = None
        self.deadline = math.inf
        """Time by which something must arrive, or ``poll`` acts."""
        self.in_progress = False
        self.progress: int | None = None
        """Last progress percentage an IN_PROGRESS ACK reported, if any."""
        self.ack: mavlink.MAVLink_command_ack_message | None = None
        """The final ACK (accepted or refused)."""
        self.error: LinkError | None = None
        self.reason = ""
        """Most recent STATUSTEXT from the vehicle since the command started."""
        self._refusal: mavlink.MAVLink_command_ack_message | None = None

    @property
    def done(self) -> bool:
        """Whether the exchange has finished, successfully or not."""
        return self.ack is not None or self.error is not None

    @property
    def succeeded(self) -> bool:
        return self.done and self.error is None

    def result(self) -> mavlink.MAVLink_command_ack_message:
        """The ACCEPTED ack; raises the exchange's error if it failed."""
        if self.error is not None:
            raise self.error
        if self.ack is None:
            raise RuntimeError("command exchange has not finished")
        return self.ack

    def _message(self) -> mavlink.MAVLink_command_long_message:
        return command_long(
            self.target_system, self.command, self.params,
            confirmation=self.sent, target_component=self.target_component,
        )  # fmt: skip

    def start(self, now: float) -> list[mavlink.MAVLink_message]:
        """The first transmission."""
        if self.started_at is not None:
            raise RuntimeError("command exchange already started")
        self.started_at = now
        msg = self._message()
        self.sent = 1
        self.deadline = now + self.timeout
        return [msg]

    def note_statustext(self, text: str, now: float) -> None:
        """Tell the exchange a STATUSTEXT the vehicle sent (kept as the refusal reason)."""
        if self.started_at is None or self.done:
            return
        self.reason = text
        if self._refusal is not None:
            self._refuse(self._refusal)

    def _refuse(self, ack: mavlink.MAVLink_command_ack_message) -> None:
        self.ack = ack
        self.error = CommandRefused(
            self.target_system, self.name, result_name(ack.result), self.reason
        )
        self.deadline = math.inf

    def matches(self, ack: mavlink.MAVLink_command_ack_message, our_system: int) -> bool:
        """Whether ``ack`` answers this exchange.

        COMMAND_ACK names the command, not the request, and is sent to every
        GCS on a shared link: ignore ACKs explicitly addressed to someone else.
        """
        # target_system is the vehicle id (its network's system id plus the network's
        # offset); the ACK comes from the system id alone.
        if ack.get_srcSystem() != sysid_of(self.target_system) or ack.command != self.command:
            return False
        target = getattr(ack, "target_system", 0)
        return target in (0, our_system)

    def receive(self, ack: mavlink.MAVLink_command_ack_message, now: float) -> None:
        """Feed a COMMAND_ACK for this command (the caller checked :meth:`matches`)."""
        if self.done or self.started_at is None:
            return
        if self._refusal is not None:
            # A refusal and an acceptance of one command cannot both be the vehicle's
            # (without signing anyone can send an ACK): the acceptance is what the
            # vehicle will act on, so it wins while the refusal waits for its reason.
            if ack.result == mavlink.MAV_RESULT_ACCEPTED:
                self._refusal, self.reason = None, ""
                self.ack = ack
                self.deadline = math.inf
            return
        if ack.result == mavlink.MAV_RESULT_IN_PROGRESS:
            self.in_progress = True
            self.progress = int(ack.progress)
            self.deadline = now + self.progress_timeout
            return
        if ack.result == mavlink.MAV_RESULT_ACCEPTED:
            self.ack = ack
            self.deadline = math.inf
        elif self.reason or self.reason_grace == 0:
            self._refuse(ack)
        else:
            # PX4 queues its STATUSTEXT through uORB and may send it after the
            # ACK: give the reason a moment to arrive before reporting.
            self._refusal = ack
            self.deadline = now + self.reason_grace

    def poll(self, now: float) -> list[mavlink.MAVLink_message]:
        """Resends due at ``now``; sets :attr:`error` once every attempt timed out."""
        if self.done or self.started_at is None or now < self.deadline:
            return []
        if self._refusal is not None:
            self._refuse(self._refusal)
            return []
        if self.in_progress or self.sent >= self.attempts:
            wait = self.progress_timeout if self.in_progress else self.timeout
            self.error = CommandTimeout(self.target_system, self.name, self.sent, wait)
            self.deadline = math.inf
            return []
        msg = self._message()
        self.sent += 1
        self.deadline = now + self.timeout
        return [msg]
