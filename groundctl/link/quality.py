"""Link quality from MAVLink sequence numbers, without I/O.

Every sender numbers its packets 0..255 per (system, component).  A jump of
more than one means packets were lost on the way.  A small step backwards is
a reordered or duplicated packet, not 255 losses: steps of more than half the
ring are read that way.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class SequenceTracker:
    """Received and lost packet counts for one vehicle (all its components)."""

    received: int = 0
    """Packets seen."""
    lost: int = 0
    """Packets inferred missing from sequence gaps."""
    reordered: int = 0
    """Packets that arrived late or twice."""
    _last: dict[int, int] = field(default_factory=dict, repr=False)

    def update(self, component: int, seq: int) -> int:
        """Account for a packet; returns how many packets were lost just before it."""
        self.received += 1
        last = self._last.get(component)
        if last is None:
            self._last[component] = seq
            return 0
        step = (seq - last) % 256
        if step == 0 or step > 128:
            self.reordered += 1
            return 0
        self._last[component] = seq
        self.lost += step - 1
        return step - 1

    @property
    def loss_ratio(self) -> float:
        """Fraction of packets lost, 0 before anything was lost or received."""
        total = self.received + self.lost
        return self.lost / total if total else 0.0
