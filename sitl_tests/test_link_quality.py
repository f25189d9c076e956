"""Sequence-number link quality over a modelled jittery, lossy link (seeded, no I/O).

The model is a 10 Hz stream whose packets each take 50 ms, give or take a
normally distributed 50 ms (never less than nothing), to arrive: neighbours
overtake each other often, and only packets that never arrive may count as
lost.
"""

from __future__ import annotations

import numpy as np
import pytest

from groundctl.link.quality import RESTART_RUN, WINDOW, SequenceTracker


def arrivals(rng: np.random.Generator, sent: int, loss: float = 0.0, rate_hz: float = 10.0,
             latency_s: float = 0.05, jitter_s: float = 0.05) -> list[int]:
    """Indices of a ``rate_hz`` stream's packets in the order they arrive."""
    sent_at = np.arange(sent) / rate_hz
    delay = np.maximum(latency_s + rng.normal(0.0, jitter_s, sent), 0.0)
    kept = rng.random(sent) >= loss
    order = np.argsort((sent_at + delay)[kept], kind="stable")
    return [int(i) for i in np.flatnonzero(kept)[order]]


def late_ones(indices: list[int]) -> int:
    """Packets that arrive after one sent later than them."""
    newest = np.maximum.accumulate(indices)
    return int(np.sum(np.asarray(indices[1:]) < newest[:-1]))


def feed(tracker: SequenceTracker, seqs: list[int], component: int = 1) -> None:
    for seq in seqs:
        tracker.update(component, seq)


@pytest.mark.parametrize("rate_hz", [10.0, 30.0])
def test_jitter_without_loss_reads_no_loss(rate_hz: float) -> None:
    rng = np.random.default_rng(11)
    indices = arrivals(rng, 3000, rate_hz=rate_hz)
    late = late_ones(indices)
    assert late > 0.04 * 3000  # the model really reorders (10 Hz: one in 18, 30 Hz: one in 3)
    t = SequenceTracker()
    feed(t, [i % 256 for i in indices])
    assert t.received == 3000
    assert t.lost == 0 and t.loss_ratio == 0.0
    assert t.reordered == late and t.duplicates == 0


@pytest.mark.parametrize(("seed", "rate_hz"), [(1, 10.0), (2, 10.0), (3, 30.0)])
def test_ten_percent_loss_with_jitter_reads_ten_percent(seed: int, rate_hz: float) -> None:
    rng = np.random.default_rng(seed)
    sent = 5000
    indices = arrivals(rng, sent, loss=0.1, rate_hz=rate_hz)
    assert late_ones(indices) > 0.04 * len(indices)
    t = SequenceTracker()
    feed(t, [i % 256 for i in indices])
    assert t.received == len(indices)
    assert t.loss_ratio == pytest.approx(0.1, abs=0.015)
    # Exactly the packets that never arrived, but for those before the first or after the
    # newest one received.
    assert t.lost == max(indices) - indices[0] + 1 - len(indices)


def test_a_late_packet_fills_its_gap() -> None:
    t = SequenceTracker()
    feed(t, [3, 4, 6])
    assert t.lost == 1
    t.update(1, 5)
    assert (t.received, t.lost, t.reordered, t.duplicates) == (4, 0, 1, 0)


def test_wrap_around_at_255() -> None:
    t = SequenceTracker()
    feed(t, [250, 251, 255, 0, 2])  # gaps 252, 253, 254 and 1, across the wrap
    assert t.lost == 4
    feed(t, [254, 1])  # late, on either side of the wrap
    assert t.lost == 2 and t.reordered == 2
    feed(t, list(range(3, 256)) + list(range(0, 10)))  # a whole turn further: no loss
    assert t.lost == 2 and t.received == 5 + 2 + 253 + 10


def test_duplicates_do_not_change_loss_or_received() -> None:
    t = SequenceTracker()
    feed(t, [10, 11, 13])
    feed(t, [13, 11, 10])  # the newest again, and two older ones again
    assert (t.received, t.lost, t.reordered, t.duplicates) == (3, 1, 3, 3)
    t.update(1, 12)  # the gap's packet, late: still fills it
    assert (t.received, t.lost, t.reordered) == (4, 0, 4)
    t.update(1, 12)  # and once more: a duplicate
    assert (t.received, t.lost, t.duplicates) == (4, 0, 4)
    assert t.loss_ratio == 0.0


def test_a_gap_is_forgotten_before_its_number_comes_round_again() -> None:
    t = SequenceTracker()
    feed(t, [0, 2])  # 1 missing
    feed(t, list(range(3, 1 + WINDOW)))  # 1 is now WINDOW - 1 positions behind
    t.update(1, 1)  # still fills its gap
    assert t.lost == 0
    feed(t, [WINDOW + 1, WINDOW + 3])  # WINDOW + 2 missing
    feed(t, [s % 256 for s in range(WINDOW + 4, 256 + WINDOW + 10)])  # the next turn, whole
    t.update(1, WINDOW + 2)  # a duplicate of this turn's, not the old gap filled
    assert t.lost == 1 and t.duplicates == 1


def test_components_have_their_own_numbering() -> None:
    t = SequenceTracker()
    feed(t, [0, 1, 3], component=1)
    feed(t, [100, 101], component=2)
    t.update(2, 2)  # far behind component 2's numbering, but component 1's gap is not its
    assert t.lost == 1
    t.update(1, 2)
    assert t.lost == 0


def test_a_reboot_does_not_read_as_255_losses() -> None:
    t = SequenceTracker()
    feed(t, list(range(0, 101)))
    feed(t, list(range(0, 60)))  # the vehicle rebooted: its numbering starts at 0 again
    assert t.lost == 0
    assert t.restarts == 1
    assert t.received == 101 + 60  # after RESTART_RUN packets the new numbering is followed
    assert t.duplicates == 0
    feed(t, [61, 62])  # and its own gaps count again
    assert t.lost == 1


def test_a_reboot_ahead_on_the_ring_costs_at_most_half_a_ring() -> None:
    t = SequenceTracker()
    feed(t, list(range(0, 201)))
    feed(t, list(range(0, 30)))  # 200 -> 0 reads as 55 packets lost; never 255
    assert t.lost == 55 and t.restarts == 0


def test_a_short_burst_of_late_duplicates_is_not_a_reboot() -> None:
    t = SequenceTracker()
    feed(t, list(range(0, 50)))
    feed(t, list(range(40, 40 + RESTART_RUN - 1)))
    assert t.restarts == 0 and t.duplicates == RESTART_RUN - 1
    assert t.received == 50 and t.lost == 0
