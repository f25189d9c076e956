"""Link quality from MAVLink sequence numbers, without I/O.

Every sender numbers its packets 0..255 per (system, component).  A jump of
more than one leaves a gap; a packet of the gap that turns up late (a
jittery link delivers out of order) fills it again, so only gaps that never
fill count as lost.  A gap stays open while it is within :data:`WINDOW`
positions of the newest packet: older ones are beyond telling apart from the
next turn of the ring and stay lost for good.

A step backwards is a late packet (it fills a gap), a duplicate (it was
received already), or, if a run of them goes on counting up, a sender that
restarted its numbering (a reboot): the tracker then follows the new
numbering instead of reading every packet as a duplicate, and no step is ever
read as 255 losses.
"""

from __future__ import annotations

from dataclasses import dataclass, field

#: Positions behind the newest packet in which a gap can still be filled.  Steps
#: of more than half the ring are read as backwards, so this is the most there is.
WINDOW = 128

#: Backward packets in a row, each a little after the one before, that mean the
#: sender restarted its numbering (reboot) rather than a burst of duplicates.
RESTART_RUN = 8

#: The most a restarted numbering may skip between two packets of such a run
#: (its own losses) and still count as one run.
RESTART_STEP = 4


@dataclass
class _Stream:
    """The numbering of one component."""

    last: int
    """Newest sequence number (the furthest along the ring)."""
    missing: set[int] = field(default_factory=set)
    """Gaps within :data:`WINDOW` of ``last`` that may still arrive."""
    run_last: int | None = None
    """Last packet of the current run of backward, counting-up packets."""
    run: int = 0
    """Length of that run."""

    def advance(self, seq: int, step: int) -> None:
        """``seq`` is ``step`` ahead of ``last``: the numbers in between are missing."""
        if step == 1 and not self.missing:  # the common case: the next, nothing owed
            self.last = seq
            self.run_last, self.run = None, 0
            return
        self.missing.update((self.last + k) % 256 for k in range(1, step))
        self.last = seq
        self.missing = {s for s in self.missing if (seq - s) % 256 < WINDOW}
        self.run_last, self.run = None, 0


@dataclass
class SequenceTracker:
    """Received and lost packet counts for one vehicle (all its components)."""

    received: int = 0
    """Unique packets seen (duplicates not counted)."""
    lost: int = 0
    """Packets of sequence gaps that never arrived (a late arrival takes its one back)."""
    reordered: int = 0
    """Packets that arrived late (filling a gap) or twice."""
    duplicates: int = 0
    """Of ``reordered``, the packets that arrived twice."""
    restarts: int = 0
    """Times a component restarted its numbering (reboot)."""
    _streams: dict[int, _Stream] = field(default_factory=dict, repr=False)

    def update(self, component: int, seq: int) -> int:
        """Account for packet ``seq`` of ``component``; returns how many packets the gap
        just before it holds (0 for a late or duplicate packet).

        A late packet that fills an earlier gap lowers :attr:`lost` by one.
        """
        stream = self._streams.get(component)
        if stream is None:
            self._streams[component] = _Stream(seq)
            self.received += 1
            return 0
        step = (seq - stream.last) % 256
        if 0 < step <= WINDOW:
            stream.advance(seq, step)
            self.received += 1
            self.lost += step - 1
            return step - 1
        self.reordered += 1
        if seq in stream.missing:  # late: its gap is filled
            stream.missing.discard(seq)
            self.received += 1
            self.lost -= 1
            return 0
        self.duplicates += 1
        self._count_restart(stream, seq)
        return 0

    def restart(self, component: int) -> None:
        """``component`` numbers its packets afresh (a reboot, or a new numbering the link
        took over): its next packet starts the count, with nothing lost in between."""
        if self._streams.pop(component, None) is not None:
            self.restarts += 1

    def _count_restart(self, stream: _Stream, seq: int) -> None:
        # A reboot restarts the numbering (at 0, usually) behind the newest packet: every
        # packet after it would read as a duplicate until the new numbering caught up.
        # Duplicates do not count up in long runs without a newer packet in between.
        prev = stream.run_last
        stream.run = stream.run + 1 if prev is not None and 0 < (seq - prev) % 256 \
            <= RESTART_STEP else 1
        stream.run_last = seq
        if stream.run < RESTART_RUN:
            return
        # The run was the sender's new numbering, not duplicates: follow it from here.
        self.received += stream.run
        self.reordered -= stream.run
        self.duplicates -= stream.run
        self.restarts += 1
        stream.last, stream.missing = seq, set()
        stream.run_last, stream.run = None, 0

    @property
    def loss_ratio(self) -> float:
        """Fraction of unique packets lost, 0 before anything was lost or received."""
        total = self.received + self.lost
        return self.lost / total if total else 0.0
