"""The dry-run's paced clock: runs at its pace, waits for a late participant (in this
process or another), never goes back, dates the past across its waits, and leaves a
participant behind that holds it too long.

Real time is involved (the clock is defined on CLOCK_MONOTONIC), so every bound
here holds however late this process is scheduled: a busy machine can only make
the clock wait longer, never run past a participant.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
import signal
import time
from multiprocessing.connection import Connection

import pytest

from groundctl.clock import PacedClock, pace_slack


def test_with_nobody_taking_part_it_runs_at_its_pace() -> None:
    clock = PacedClock(50.0)
    # The real time is read outside the clock's readings, so that it spans them however
    # long the process was kept from running between two reads (a busy machine).
    w0 = time.monotonic()
    t0 = clock.now()
    time.sleep(0.05)
    t1 = clock.now()
    w1 = time.monotonic()
    # 50x: 0.05 s of real time is at least 2.5 s, at most 50x the real time that passed.
    assert 2.5 <= t1 - t0 <= 50.0 * (w1 - w0) + 1e-6


def test_a_late_participant_holds_it_and_it_resumes_from_where_it_waited() -> None:
    clock = PacedClock(100.0, slack=0.05)
    me = clock.participant(0)
    me.idle_until(0.5)
    time.sleep(0.05)  # 5 s at full pace: the clock waits at 0.5 + slack for us
    held = me.now()
    assert held == pytest.approx(0.55)
    time.sleep(0.02)
    assert me.now() == pytest.approx(0.55)  # still waiting
    w = time.monotonic()
    me.idle_until(2.0)
    resumed = me.now()
    # Rises from where it waited, not by the 7 s of real time that passed at its pace.
    assert 0.55 <= resumed <= 0.55 + 100.0 * (time.monotonic() - w) + 1e-6
    time.sleep(0.05)
    assert me.now() == pytest.approx(2.05)  # and waits again at the next due time
    assert clock.held_s()[0] >= 0.05  # real seconds it waited for slot 0
    assert clock.held_s()[1] == 0.0


def test_the_dry_run_slack_is_a_few_milliseconds_of_real_time() -> None:
    # x1 and x2 (the README's demo): 6.25 ms of real time past the late participant, as
    # clock time; from x8 on, 50 ms of clock time (the fast rehearsals, as before).
    assert pace_slack(1.0) == pytest.approx(0.00625)
    assert pace_slack(2.0) == pytest.approx(0.0125)
    assert pace_slack(8.0) == pytest.approx(0.05)
    assert pace_slack(100.0) == pytest.approx(0.05)
    assert pace_slack(0.25) / 0.25 == pytest.approx(0.00625)
    clock = PacedClock(1.0, slack=pace_slack(1.0))
    me = clock.participant(0)
    me.idle_until(0.0)  # held from here on (however late this process ran until now)
    t = me.now()
    me.idle_until(t + 0.1)
    time.sleep(0.15)  # x1: the clock waits for us 6.25 ms past our due time, not 50
    assert me.now() == pytest.approx(t + 0.10625)


def test_it_never_goes_back_when_a_participant_reports_an_earlier_time() -> None:
    clock = PacedClock(100.0)
    a, b = clock.participant(0), clock.participant(1)
    a.idle_until(1.0)
    time.sleep(0.03)
    assert a.now() == pytest.approx(1.05)
    b.idle_until(0.2)  # joins late, behind the clock: it stands still, not back
    assert b.now() == pytest.approx(1.05)
    b.idle_until(math.inf)
    assert a.now() == pytest.approx(1.05)
    seen = [a.now() for _ in range(1000)]
    assert seen == sorted(seen)


def test_the_past_is_dated_on_the_clock_as_it_ran() -> None:
    clock = PacedClock(10.0, slack=0.05)
    me = clock.participant(0)
    me.idle_until(0.3)
    time.sleep(0.08)  # reaches 0.35 after 0.035 s, then waits
    during_wait = time.monotonic()
    time.sleep(0.05)
    assert me.now() == pytest.approx(0.35)
    assert clock.at_wall(during_wait) == pytest.approx(0.35)
    me.idle_until(10.0)
    time.sleep(0.03)
    # A datagram stamped during the wait is 0.35 on this clock, not "now minus its real
    # age at full pace" (which would put it before the wait).
    assert clock.at_wall(during_wait) == pytest.approx(0.35)
    age = time.monotonic() - during_wait
    now, (then,) = me.dated([age])
    assert now - then == pytest.approx(me.now() - 0.35, abs=0.02)
    # A drain's datagrams dated with one look: the one of the wait, and one just read.
    age = time.monotonic() - during_wait
    now, (first, last) = me.dated([age, 0.0])
    assert first == pytest.approx(0.35, abs=0.02) and last == pytest.approx(now)
    assert now == pytest.approx(me.now(), abs=0.02)
    assert me.dated([age])[1] == [pytest.approx(0.35, abs=0.02)] and me.dated([])[1] == []


def test_a_participant_holding_it_longer_than_the_valve_is_left_behind() -> None:
    # A valve ten times the first wait: on a busy machine a 0.05 s sleep can take 0.1 s
    # or more, and the valve opened before the first look (measured: 0.43, not 0.25).
    clock = PacedClock(100.0, valve_s=0.5)
    me, other = clock.participant(0), clock.participant(1)
    me.idle_until(0.2)
    time.sleep(0.05)
    assert other.now() == pytest.approx(0.25)
    time.sleep(0.5)  # frozen past the valve: the clock runs on without it, from where
    assert other.now() == pytest.approx(0.25)  # it waited (no jump by the time it waited)
    assert clock.left_behind() == [1, 0]
    time.sleep(0.02)
    assert other.now() > 1.0
    now = other.now()
    me.idle_until(now + 1.0)  # back: it takes part again
    time.sleep(0.05)
    assert other.now() == pytest.approx(now + 1.05, abs=0.01)


def _child(clock: PacedClock, conn: Connection) -> None:
    me = clock.participant(1)
    due = me.now() + 1.0
    me.idle_until(due)
    conn.send(due)
    conn.recv()  # until the parent has seen the clock wait for us
    me.idle_until(math.inf)
    conn.send("released")


def test_a_participant_in_another_process_holds_it() -> None:
    clock = PacedClock(100.0)
    ctx = mp.get_context("spawn")
    ours, theirs = ctx.Pipe()
    child = ctx.Process(target=_child, args=(clock, theirs), daemon=True)
    child.start()
    try:
        assert ours.poll(60.0)
        due = ours.recv()
        time.sleep(0.05)  # 5 s at full pace
        assert clock.now() == pytest.approx(due + 0.05)
        ours.send("go")
        assert ours.poll(60.0) and ours.recv() == "released"
        time.sleep(0.02)
        assert clock.now() > due + 1.0
    finally:
        child.join(10.0)
        if child.is_alive():
            child.kill()
    assert clock.held_s()[1] > 0.0


@pytest.mark.parametrize("bad", [{"speed": 0.0}, {"participants": 0}, {"slack": 0.0},
                                 {"valve_s": -1.0}])
def test_bad_arguments_name_the_parameter(bad: dict[str, float]) -> None:
    name = next(iter(bad))
    with pytest.raises(ValueError, match=f"`{name}`"):
        PacedClock(**bad)  # type: ignore[arg-type]


def test_only_a_participant_can_say_it_is_idle() -> None:
    clock = PacedClock(1.0)
    with pytest.raises(ValueError, match="participant"):
        clock.idle_until(1.0)
    with pytest.raises(ValueError, match="`slot`"):
        clock.participant(2)


def test_the_valve_counts_from_when_a_participant_began_to_hold_not_its_last_report() -> None:
    # Wall-clock margins of a second (the valve), so that a busy machine's scheduling
    # (threads preempted for tens of milliseconds) cannot change the outcome.
    for _ in range(50):
        clock = PacedClock(100.0, valve_s=1.0)
        early, late = clock.participant(0), clock.participant(1)
        early.idle_until(5.0)  # reports once, long before it holds the clock
        late.idle_until(0.2)
        # Both reported before the clock (x100) ran past 0.25: this process was not kept
        # from running for 2.5 ms meanwhile (a busy machine's scheduling); else again.
        if early.now() <= 0.25 + 1e-9:
            break
    else:
        pytest.fail("the two reports never came within 2.5 ms of the clock's start")
    time.sleep(1.5)
    w = time.monotonic()
    resumed = early.now()  # the late one held it past the valve: left behind, and the
    # clock goes on from where it waited (by at most what ran at x100 during this call)
    assert 0.25 - 1e-9 <= resumed <= 0.25 + 100.0 * (time.monotonic() - w) + 1e-6
    assert clock.left_behind() == [0, 1]
    time.sleep(0.2)  # the clock reaches 5.05 (48 ms at x100) and waits there for the
    assert early.now() == pytest.approx(5.05)  # early one, which is not left behind at once
    assert clock.left_behind() == [0, 1]


def _die_holding_the_lock(clock: PacedClock) -> None:
    clock._lock.acquire()
    os.kill(os.getpid(), signal.SIGKILL)


def test_a_process_killed_while_it_holds_the_lock_hangs_nobody(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(PacedClock, "LOCK_TIMEOUT_S", 0.2)
    clock = PacedClock(10.0)
    before = clock.now()
    ctx = mp.get_context("spawn")
    child = ctx.Process(target=_die_holding_the_lock, args=(clock,), daemon=True)
    child.start()
    child.join(60.0)
    assert child.exitcode == -signal.SIGKILL
    t0 = time.monotonic()
    first = clock.now()  # waits LOCK_TIMEOUT_S, then runs on from what it last saw
    assert time.monotonic() - t0 < 5.0
    time.sleep(0.05)
    assert before <= first < clock.now()
    clock.participant(0).idle_until(1.0)  # does not hang either
    # Nor the report's figures (a dry-run whose simulator was killed hung in them) or
    # the dating of a link worker's batch.
    assert len(clock.held_s()) == 2 and clock.left_behind() == [0, 0]
    assert len(clock.dated([0.0, 0.01])[1]) == 2 and len(clock.dated([0.01])[1]) == 1
    # Only the first reading waited: every later one only looks at the lock (a dry-run
    # whose simulator died holding it waited at every reading, 2 s each, and never ended).
    asked: list[float] = []
    lock = clock._lock

    class Recording:
        def acquire(self, timeout: float) -> bool:
            asked.append(timeout)
            return bool(lock.acquire(timeout=timeout))

        def release(self) -> None:
            lock.release()

    clock._lock = Recording()
    readings = [clock.now() for _ in range(20)]
    assert asked == [0.0] * 20 and readings == sorted(readings)
