"""The runner's LED stage (groundctl/flight/runner/leds.py): a colour change sent its
vehicle's one-way delay ahead of its instant, on the clock between ticks; the tick's own
colours while the show clock does not run; a refresh once a second; a vehicle back from
a silence sent its colour afresh; a send the link refuses costs only that send."""

from __future__ import annotations

import asyncio
from collections.abc import Sequence

import numpy as np
import pytest
from test_execute_leds import SYSIDS, schedule

from groundctl.clock import HELD_POLL_S, ManualClock
from groundctl.errors import LinkError
from groundctl.flight.runner.leds import LedSends, link_delays

ORANGE = (255, 128, 0)
BLACK = (0, 0, 0)


class Sent:
    """What the stage handed the link: (clock time, system id, colour)."""

    def __init__(self, clock: ManualClock, refuse: Sequence[int] = ()) -> None:
        self.clock = clock
        self.refuse = set(refuse)
        self.log: list[tuple[float, int, tuple[int, int, int]]] = []

    def __call__(self, sysid: int, r: int, g: int, b: int) -> None:
        if sysid in self.refuse:
            raise LinkError(f"vehicle {sysid}: address unknown (never heard from it)")
        self.log.append((self.clock.now(), sysid, (r, g, b)))

    def to(self, sysid: int) -> list[tuple[float, tuple[int, int, int]]]:
        return [(t, c) for t, s, c in self.log if s == sysid]


def stage(clock: ManualClock, sent: Sent, delays: Sequence[float] = (0.03, 0.0, 0.0),
          idles: list[float] | None = None) -> LedSends:
    leds = LedSends(clock, sent, lambda ids: np.array(delays, dtype=float)[:len(ids)],
                    lambda: idles.append(clock.now()) if idles is not None else None,
                    period_s=0.1, refresh_s=1.0)
    leds.schedule = schedule()
    return leds


async def settle(until: float | None = None, clock: ManualClock | None = None) -> None:
    """Let the loop's timers run (and move the clock to ``until`` first)."""
    if clock is not None and until is not None:
        clock.advance(until - clock.now())
    for _ in range(10):  # a send the clock was not ready for polls again: HELD_POLL_S
        await asyncio.sleep(HELD_POLL_S / 2)


def test_a_change_leaves_its_delay_ahead_of_its_instant_and_not_before() -> None:
    async def main() -> None:
        clock = ManualClock(100.0)  # show time 0 at clock time 100
        sent, idles = Sent(clock), []
        leds = stage(clock, sent, idles=idles)
        idles.clear()
        black = np.zeros((3, 3))
        for tick in range(20, 21):  # the tick at show time 1.9: the window (1.9, 2.0]
            now = 100.0 + tick * 0.1 - 0.1
            clock.advance(now - clock.now())
            leds.tick(now, now - 100.0, list(SYSIDS), black)
        # Vehicle 11 (30 ms ahead) turns orange at show time 2.0: due at 1.97 (beside
        # vehicle 13's steps of a slow fade).
        assert any(due == pytest.approx(101.97) for due in leds.dues())
        await settle(101.96, clock)
        assert ORANGE not in [c for _, c in sent.to(11)]  # not a moment early
        await settle(101.97, clock)
        assert sent.to(11)[-1] == (pytest.approx(101.97), ORANGE)
        assert all(due > 101.97 for due in leds.dues())
        assert idles and idles[-1] == pytest.approx(101.97)
        # Vehicle 12 (no delay) changes at 2.0 itself: the next window's.
        assert ORANGE not in [c for _, c in sent.to(12)]
        leds.tick(102.0, 2.0, list(SYSIDS), black)
        await settle(102.0, clock)
        assert sent.to(12)[-1] == (pytest.approx(102.0), ORANGE)
        leds.cancel()

    asyncio.run(main())


def test_without_the_show_clock_the_ticks_own_colours_change_and_refresh() -> None:
    async def main() -> None:
        clock = ManualClock(0.0)
        sent = Sent(clock)
        leds = stage(clock, sent)
        leds.tick(10.0, 1.9, list(SYSIDS), np.zeros((3, 3)))  # a change is scheduled ...
        assert leds.dues()
        blue = np.array([[0, 0, 255]] * 3)
        clock.advance(10.05)
        leds.tick(10.05, None, list(SYSIDS), blue)  # ... and the clock is held: dropped
        assert leds.dues() == []
        await settle(12.0, clock)
        assert [c for _, c in sent.to(11)][-1] == (0, 0, 255)
        n = len(sent.log)
        leds.tick(10.1, None, list(SYSIDS), blue)  # unchanged: nothing sent
        assert len(sent.log) == n
        leds.tick(11.06, None, list(SYSIDS), blue)  # a second on: every colour again
        assert len(sent.log) == n + 3
        leds.forget(12)  # heard again after a silence: afresh at once
        leds.tick(11.1, None, list(SYSIDS), blue)
        assert sent.log[-1][1:] == (12, (0, 0, 255)) and len(sent.log) == n + 4

    asyncio.run(main())


def test_the_refresh_repeats_the_colour_the_vehicle_should_show_on_arrival() -> None:
    async def main() -> None:
        clock = ManualClock(100.0)
        sent = Sent(clock)
        leds = stage(clock, sent)
        leds.tick(100.0, 0.0, list(SYSIDS), np.zeros((3, 3)))  # never sent: refreshed now
        assert sorted(s for _, s, _ in sent.log) == list(SYSIDS)
        assert all(c == BLACK for _, s, c in sent.log if s != 13)
        sent.log.clear()
        clock.advance(2.5)  # show time 2.5: orange since 2.0 on tracks 0 and 1
        leds.tick(102.5, 2.5, list(SYSIDS), np.zeros((3, 3)))
        assert dict((s, c) for _, s, c in sent.log)[11] == ORANGE
        leds.cancel()

    asyncio.run(main())


def test_a_send_the_link_refuses_costs_only_that_send() -> None:
    async def main() -> None:
        clock = ManualClock(100.0)
        sent = Sent(clock, refuse=[11])
        leds = stage(clock, sent, delays=(0.03, 0.03, 0.0))
        leds.tick(101.9, 1.9, list(SYSIDS), np.zeros((3, 3)))
        await settle(102.0, clock)  # 11 and 12 turn orange in one group, at 1.97
        assert sent.to(11) == [] and sent.to(12)[-1] == (pytest.approx(102.0), ORANGE)
        assert leds.dues() == []
        leds.tracker.forget(11)

    asyncio.run(main())


def test_link_delays_are_half_the_round_trip_bounded() -> None:
    rtts = {1: 0.04, 2: None, 3: 5.0, 4: -0.01}
    assert link_delays(rtts.get, [1, 2, 3, 4, 9]).tolist() == [0.02, 0.0, 1.0, 0.0, 0.0]


def test_a_dark_vehicle_no_longer_streamed_is_turned_off_and_kept_off() -> None:
    """A drone that left the show and came down in its own land mode is not streamed any
    more: its LEDs are turned off all the same, refreshed once a second; a dark
    vehicle still streamed gets no colour change of its track; one never lit is left
    alone."""
    async def main() -> None:
        clock = ManualClock(100.0)
        sent = Sent(clock)
        leds = stage(clock, sent)
        lit = np.array([ORANGE] * 3)
        leds.tick(100.0, None, list(SYSIDS), lit)
        assert all(c == ORANGE for _, _, c in sent.log)
        sent.log.clear()
        streamed = [s for s in SYSIDS if s != 12]
        leds.tick(100.1, None, streamed, lit[:2], dark={12, 13})
        assert sorted(sent.log) == [(100.0, 12, BLACK), (100.0, 13, BLACK)]
        sent.log.clear()
        leds.tick(100.2, None, streamed, lit[:2], dark={12, 13})
        assert sent.log == []  # off already: nothing again before the refresh
        clock.advance(1.0)
        leds.tick(101.2, None, streamed, lit[:2], dark={12, 13})
        assert sorted(s for _, s, c in sent.log if c == BLACK) == [12, 13]
        assert all(c == BLACK for _, s, c in sent.log if s != 11)
        # One never lit and not streamed (a spare waiting on its pad): left alone.
        sent.log.clear()
        leds.tick(101.3, None, streamed, lit[:2], dark={12, 13, 14})
        assert [s for _, s, _ in sent.log if s == 14] == []

    asyncio.run(main())
