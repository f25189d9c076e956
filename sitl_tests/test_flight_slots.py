"""A tick's setpoints spread over its period (groundctl/flight/runner/slots.py): which
vehicle leaves when, each slot at its own instant on the clock, the tick's lateness
its last slot's, and a tick that begins before the last one's slots have left; the clock timers
beneath them (groundctl/flight/runner/timers.py)."""

from __future__ import annotations

import asyncio

import pytest

from groundctl.clock import ManualClock
from groundctl.flight.runner.slots import Send, SendSlots, slot_delays
from groundctl.flight.runner.timers import ClockTimers


def test_the_fleet_is_cut_into_even_slots_of_at_most_so_many() -> None:
    assert slot_delays(0, 64, 0.1).tolist() == []
    assert slot_delays(64, 64, 0.1).tolist() == [0.0] * 64  # a fleet of one slot: a burst
    d = slot_delays(254, 64, 0.1)
    assert sorted(set(d.tolist())) == pytest.approx([0.0, 0.025, 0.05, 0.075])
    assert max(list(d).count(x) for x in set(d)) <= 64
    assert list(d) == sorted(d)  # consecutive vehicles share a slot
    d = slot_delays(1000, 64, 0.1)
    assert len(set(d.tolist())) == 16 and d.max() < 0.1


def _sends(*sysids: int) -> list[Send]:
    return [(s, 0, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]) for s in sysids]


def test_each_slot_leaves_at_its_own_instant() -> None:
    async def main() -> None:
        clock = ManualClock(10.0)
        sent: list[tuple[float, int]] = []
        done: list[float] = []
        idles: list[float] = []
        slots = SendSlots(clock, lambda s, *_: sent.append((clock.now(), s)), done.append,
                          lambda: idles.append(clock.now()))
        slots.start(10.0, 10.0, [(0.0, _sends(1, 2)), (0.05, _sends(3))])
        assert sent == [(10.0, 1), (10.0, 2)] and done == []
        assert slots.dues() == [10.05]
        await asyncio.sleep(0.01)
        assert len(sent) == 2  # the clock is not there yet
        clock.advance(0.05)
        for _ in range(50):
            await asyncio.sleep(0.005)
            if done:
                break
        assert sent[-1] == (10.05, 3)
        assert done == [pytest.approx(0.0)]
        assert slots.dues() == [] and len(idles) == 2

    asyncio.run(main())


def test_a_late_slot_is_sent_before_the_next_tick_and_counts_as_late() -> None:
    async def main() -> None:
        clock = ManualClock(0.0)
        sent: list[int] = []
        done: list[float] = []
        slots = SendSlots(clock, lambda s, *_: sent.append(s), done.append, lambda: None)
        slots.start(0.0, 0.0, [(0.0, _sends(1)), (0.05, _sends(2))])
        clock.advance(0.12)  # the loop was busy: the next tick begins at 0.12
        slots.start(0.1, 0.12, [(0.0, _sends(1)), (0.05, _sends(2))])
        assert sent == [1, 2, 1]  # the late slot left first
        assert done == [pytest.approx(0.07)]  # 0.12 against its instant 0.05
        slots.cancel()
        assert slots.dues() == []

    asyncio.run(main())


def test_a_call_waits_for_its_clock_instant_and_is_made_once() -> None:
    async def main() -> None:
        clock = ManualClock(0.0)  # real time does not move it: every timer fires early
        made: list[tuple[str, float]] = []
        timers = ClockTimers(clock)
        a = timers.add(0.5, 0.5, lambda: made.append(("a", clock.now())))
        timers.add(0.8, 0.8, lambda: made.append(("b", clock.now())))
        c = timers.add(0.9, 0.9, lambda: made.append(("c", clock.now())))
        await asyncio.sleep(0.02)
        assert made == [] and sorted(timers.dues()) == [0.5, 0.8, 0.9]  # armed again
        clock.advance(0.5)
        await asyncio.sleep(0.02)
        assert made == [("a", 0.5)] and timers.pending() == [a + 1, c]
        timers.fire(a)  # made already: nothing
        timers.fire(c, force=True)  # now, whatever the clock says
        assert made[-1] == ("c", 0.5) and len(timers) == 1
        timers.cancel()
        clock.advance(1.0)
        await asyncio.sleep(0.02)
        assert [name for name, _ in made] == ["a", "c"] and timers.dues() == []

    asyncio.run(main())
