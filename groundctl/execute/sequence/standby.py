"""What the sequence keeps of its spares: each one waiting on its pad
(:class:`Standby`), and each track one was sent into (:class:`Replacement`, the
report's ``spares.replacements``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from groundctl.link.flavours import Flavour


@dataclass
class Standby:
    """A spare waiting on its pad."""

    sysid: int
    """Its system id."""
    flavour: Flavour
    """Its autopilot family."""
    pad: int
    """Its pad (index into the plan's spare pads)."""
    sent: bool = False
    """Sent into a track (it has a run in :attr:`SequenceState.vehicles` from then on)."""
    tried: set[int] = field(default_factory=set)
    """Tracks it failed to join."""


@dataclass
class Replacement:
    """One track taken over: for the report's ``spares.replacements``."""

    track: int
    failed: int
    spare: int
    left_at: float | None
    """Show time the failed drone left the track, s."""
    joined_at: float | None = None
    """Show time the spare was on the track's plan, s (None: it never got there)."""
    plan_ms: float = 0.0
    outcome: str = "planned"
    """``planned``, ``joined`` or ``failed`` (with why)."""

    def as_dict(self) -> dict[str, object]:
        dark = None if self.joined_at is None or self.left_at is None \
            else round(self.joined_at - self.left_at, 2)
        return {"track": self.track, "failed": self.failed, "spare": self.spare,
                "left_at": None if self.left_at is None else round(self.left_at, 2),
                "joined_at": None if self.joined_at is None else round(self.joined_at, 2),
                "dark_s": dark, "plan_ms": round(self.plan_ms, 1), "outcome": self.outcome}
