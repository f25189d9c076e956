"""The COMMAND_LONG/ACK exchange, driven by hand with a manual clock."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.clock import ManualClock
from groundctl.errors import CommandRefused, CommandTimeout
from groundctl.link.command import CommandExchange

ARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM


def ack(command: int, result: int, src: int = 3, target: int = 255) -> mavlink.MAVLink_message:
    mav = mavlink.MAVLink(None, srcSystem=src, srcComponent=1)
    (msg,) = mavlink.MAVLink(None).parse_buffer(
        mav.command_ack_encode(command, result, 0, 0, target, 190).pack(mav))
    return msg


def test_accepted_first_time() -> None:
    clock = ManualClock()
    ex = CommandExchange(3, ARM, (1,), timeout=1.0, attempts=3)
    (sent,) = ex.start(clock.now())
    assert sent.command == ARM and sent.param1 == 1 and sent.confirmation == 0
    clock.advance(0.1)
    a = ack(ARM, mavlink.MAV_RESULT_ACCEPTED)
    assert ex.matches(a, 255)
    ex.receive(a, clock.now())
    assert ex.done and ex.succeeded and ex.result() is a


def test_resends_with_incremented_confirmation_then_times_out() -> None:
    clock = ManualClock()
    ex = CommandExchange(3, ARM, (1,), timeout=1.0, attempts=3)
    ex.start(clock.now())
    clock.advance(0.99)
    assert ex.poll(clock.now()) == []
    confirmations = []
    for _ in range(2):
        clock.advance(1.0)
        (resent,) = ex.poll(clock.now())
        confirmations.append(resent.confirmation)
    assert confirmations == [1, 2]
    clock.advance(1.0)
    assert ex.poll(clock.now()) == []
    assert ex.done
    with pytest.raises(CommandTimeout) as info:
        ex.result()
    assert info.value.attempts == 3 and info.value.system_id == 3
    assert "MAV_CMD_COMPONENT_ARM_DISARM after 3 attempts" in str(info.value)


def test_ack_after_a_retry_succeeds() -> None:
    clock = ManualClock()
    ex = CommandExchange(3, ARM, (1,), timeout=0.5, attempts=2)
    ex.start(clock.now())
    clock.advance(0.6)
    assert len(ex.poll(clock.now())) == 1
    ex.receive(ack(ARM, mavlink.MAV_RESULT_ACCEPTED), clock.now())
    assert ex.succeeded


def test_refusal_carries_statustext_reason() -> None:
    clock = ManualClock()
    ex = CommandExchange(3, ARM, (1,))
    ex.start(clock.now())
    ex.note_statustext("Arm: Need Position Estimate", clock.now())
    ex.receive(ack(ARM, mavlink.MAV_RESULT_FAILED), clock.now())
    with pytest.raises(CommandRefused) as info:
        ex.result()
    err = info.value
    assert (err.system_id, err.result, err.reason) == (3, "MAV_RESULT_FAILED",
                                                       "Arm: Need Position Estimate")
    assert str(err) == ("vehicle 3: MAV_CMD_COMPONENT_ARM_DISARM refused (MAV_RESULT_FAILED): "
                        "Arm: Need Position Estimate")


def test_refusal_waits_briefly_for_a_late_reason() -> None:
    clock = ManualClock()
    ex = CommandExchange(3, ARM, (1,), reason_grace=0.2)
    ex.start(clock.now())
    ex.receive(ack(ARM, mavlink.MAV_RESULT_DENIED), clock.now())
    assert not ex.done
    clock.advance(0.05)
    ex.note_statustext("Arming denied: no GPS", clock.now())
    assert ex.done and ex.error is not None and ex.error.reason == "Arming denied: no GPS"

    ex2 = CommandExchange(3, ARM, (1,), reason_grace=0.2)
    ex2.start(clock.now())
    ex2.receive(ack(ARM, mavlink.MAV_RESULT_DENIED), clock.now())
    clock.advance(0.3)
    assert ex2.poll(clock.now()) == [] and ex2.done
    assert isinstance(ex2.error, CommandRefused) and ex2.error.reason == ""


def test_in_progress_keeps_waiting_without_resending() -> None:
    clock = ManualClock()
    ex = CommandExchange(3, ARM, (1,), timeout=1.0, attempts=3, progress_timeout=4.0)
    ex.start(clock.now())
    ex.receive(ack(ARM, mavlink.MAV_RESULT_IN_PROGRESS), clock.now())
    clock.advance(3.0)
    assert ex.poll(clock.now()) == [] and not ex.done
    ex.receive(ack(ARM, mavlink.MAV_RESULT_ACCEPTED), clock.now())
    assert ex.succeeded

    ex2 = CommandExchange(3, ARM, (1,), timeout=1.0, progress_timeout=4.0)
    ex2.start(clock.now())
    ex2.receive(ack(ARM, mavlink.MAV_RESULT_IN_PROGRESS), clock.now())
    clock.advance(4.1)
    assert ex2.poll(clock.now()) == []
    assert isinstance(ex2.error, CommandTimeout)


def test_matches_only_our_command_from_our_vehicle() -> None:
    ex = CommandExchange(3, ARM, (1,))
    assert not ex.matches(ack(ARM, 0, src=4), 255)
    assert not ex.matches(ack(mavlink.MAV_CMD_DO_SET_MODE, 0), 255)
    assert not ex.matches(ack(ARM, 0, target=254), 255)  # for another ground station
    assert ex.matches(ack(ARM, 0, target=0), 255)


def test_argument_errors_name_the_parameter() -> None:
    with pytest.raises(ValueError, match="`timeout`"):
        CommandExchange(1, ARM, timeout=0)
    with pytest.raises(ValueError, match="`attempts`"):
        CommandExchange(1, ARM, attempts=0)
