"""Seeded fault knobs: a bad radio link and physical failures.

Link faults act on every datagram in both directions, in simulated time, like
trio's fake network: each packet may be lost, duplicated, delayed by
``latency ± jitter``, or dropped while the link is cut.  The jitter is a queue's: a
delay that wanders (:class:`Jitter`), first in first out, as on a radio or one network
path, not each packet shuffled on its own (a burst of 60 PARAM_VALUEs shuffled over
50 ms of independent jitter read as dozens of packets "not fitting the numbering").  Physical faults
(GPS glitch, motor failure, low battery, gust) are :class:`FaultEvent` values
scheduled on the fleet by system id or fleet-wide.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LinkFaults:
    """A lossy, slow, duplicating or cut link (applied per packet, both directions)."""

    loss: float = 0.0
    """Probability that a packet is dropped."""
    latency_ms: float = 0.0
    """Mean one-way delay added to every packet, milliseconds of simulated time."""
    jitter_ms: float = 0.0
    """Standard deviation of the delay (normal, clipped at zero), milliseconds."""
    duplicate: float = 0.0
    """Probability that a packet is delivered twice."""
    cut_at: float | None = None
    """Simulated time (s since boot) from which nothing gets through; None: never."""
    restore_at: float | None = None
    """Simulated time at which a cut link comes back; None: stays cut."""

    def __post_init__(self) -> None:
        for name in ("loss", "duplicate"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"`{name}` must be a probability in [0, 1], not {value}")
        for name in ("latency_ms", "jitter_ms"):
            if getattr(self, name) < 0:
                raise ValueError(f"`{name}` must be non-negative")
        if (self.cut_at is not None and self.restore_at is not None
                and self.restore_at < self.cut_at):
            raise ValueError("`restore_at` must not be before `cut_at`")

    @property
    def is_clean(self) -> bool:
        """True when this link changes nothing (the fast path)."""
        return (self.loss == 0 and self.latency_ms == 0 and self.jitter_ms == 0
                and self.duplicate == 0 and self.cut_at is None)

    def is_cut(self, now: float) -> bool:
        """Whether the link is cut at simulated time ``now``."""
        if self.cut_at is None or now < self.cut_at:
            return False
        return self.restore_at is None or now < self.restore_at

    def deliveries(self, now: float, rng: np.random.Generator,
                   jitter: Jitter | None = None) -> list[float]:
        """Delays (s) after which a packet sent at ``now`` arrives: [] lost, 2 duplicated;
        ``jitter`` the link direction's wandering delay (None: each packet's own)."""
        if self.is_clean:
            return [0.0]
        if self.is_cut(now):
            return []
        if self.loss and rng.random() < self.loss:
            return []
        copies = 2 if self.duplicate and rng.random() < self.duplicate else 1
        delays = []
        for _ in range(copies):
            if jitter is not None:
                delay = jitter.sample(now, self.latency_ms, self.jitter_ms, rng)
            else:
                delay = self.latency_ms + (float(rng.normal(0.0, self.jitter_ms))
                                           if self.jitter_ms else 0.0)
            delays.append(max(0.0, delay) / 1000.0)
        return delays


#: How fast a link's queueing delay wanders, s (an Ornstein-Uhlenbeck time constant).
JITTER_TAU_S = 0.2


class Jitter:
    """One link direction's extra delay: normal with the jitter's standard deviation over
    time, wandering with :data:`JITTER_TAU_S` between packets (a queue that fills and
    drains), and first in, first out: no packet overtakes an earlier one."""

    def __init__(self) -> None:
        self._at: float | None = None
        self._unit = 0.0  # the wandering delay in standard deviations
        self._last_arrival = -math.inf

    def sample(self, now: float, base_ms: float, std_ms: float,
               rng: np.random.Generator) -> float:
        """The delay of a packet sent at ``now`` over a link of ``base_ms`` latency,
        milliseconds (never negative, never arriving before the packet before it)."""
        if self._at is None:
            self._unit = float(rng.standard_normal())
        else:
            keep = math.exp(-max(now - self._at, 0.0) / JITTER_TAU_S)
            self._unit = self._unit * keep + math.sqrt(1.0 - keep * keep) \
                * float(rng.standard_normal())
        self._at = now
        delay = max(base_ms + self._unit * std_ms, 0.0, (self._last_arrival - now) * 1000.0)
        self._last_arrival = now + delay / 1000.0
        return delay


#: A ``--fail`` battery leaves this fraction of the level at which a drone leaves the show
#: (``[limits] land_battery_pct``): below it, above the half at which it would land where
#: it is, so the ground station flies it out on a way out.
FAILED_BATTERY_SHARE = 0.75


def failed_battery(land_battery_pct: float) -> float:
    """What a ``--fail`` battery leaves in the pack, fraction, for a show that lands a
    drone at ``land_battery_pct`` percent."""
    return FAILED_BATTERY_SHARE * land_battery_pct / 100.0


class FaultKind(enum.StrEnum):
    """Physical faults the simulator can inject."""

    GPS_GLITCH = "gps_glitch"
    """The position estimate jumps by ``vector`` (ENU m) for ``duration`` s (None: for good)."""
    MOTOR_FAILURE = "motor_failure"
    """Thrust is lost: the vehicle falls and crashes."""
    LOW_BATTERY = "low_battery"
    """The battery drops to ``value`` (fraction of capacity) at once."""
    GUST = "gust"
    """Extra wind ``vector`` (ENU m/s) for ``duration`` s."""
    PUSH = "push"
    """The vehicle is displaced by ``vector`` (ENU m) over ``duration`` s (default 1): a
    gust, a bird, a GPS jump corrected; its autopilot then fights its way back."""
    WEAK = "weak"
    """Its speed and acceleration authority scales by ``value`` (a weak motor or battery:
    it cannot keep up)."""


@dataclass(frozen=True)
class FaultEvent:
    """A physical fault scheduled at a simulated time for some vehicles."""

    kind: FaultKind
    """What goes wrong."""
    at: float
    """Simulated time (s) at which it happens."""
    sysid: int | None = None
    """Target vehicle; None: the whole fleet."""
    vector: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Offset (GPS glitch, m) or wind (gust, m/s), ENU."""
    duration: float | None = None
    """How long a glitch or gust lasts, s; None: for good (glitch) / 0 is invalid (gust)."""
    value: float = 0.0
    """Remaining battery fraction for LOW_BATTERY."""

    def __post_init__(self) -> None:
        if self.duration is not None and not self.duration > 0:
            raise ValueError("`duration` must be positive")
        if self.kind is FaultKind.GUST and self.duration is None:
            raise ValueError("a gust needs a `duration`")
        if not 0.0 <= self.value <= 1.0:
            raise ValueError("`value` must be a fraction in [0, 1]")
        if self.kind is FaultKind.WEAK and not self.value > 0:
            raise ValueError("a weak vehicle needs a factor `value` in (0, 1]")
        if not all(math.isfinite(v) for v in self.vector):
            raise ValueError("`vector` must be finite")
