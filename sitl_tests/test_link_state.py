"""Per-vehicle state decoding (both flavours), sequence-gap loss, TIMESYNC estimation."""

from __future__ import annotations

import numpy as np
import pymap3d
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.flavours import Flavour, encode_mode
from groundctl.link.quality import SequenceTracker
from groundctl.link.state import VehicleState, apply
from groundctl.link.timesync import NS, TimesyncEstimator, answer


class Vehicle:
    """Encodes messages as a vehicle would and decodes them as the link does."""

    def __init__(self, sysid: int = 3, comp: int = 1) -> None:
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=comp)
        self.rx = mavlink.MAVLink(None)

    def __call__(self, msg: mavlink.MAVLink_message) -> mavlink.MAVLink_message:
        data = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        (out,) = self.rx.parse_buffer(data)
        return out

    def heartbeat(self, flavour: Flavour, mode: str, armed: bool = False,
                  autopilot: int | None = None) -> mavlink.MAVLink_message:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        return self(self.mav.heartbeat_encode(
            mavlink.MAV_TYPE_QUADROTOR,
            flavour.mav_autopilot if autopilot is None else autopilot,
            base, encode_mode(flavour, mode), mavlink.MAV_STATE_ACTIVE))


@pytest.mark.parametrize(
    ("flavour", "mode"),
    [(Flavour.ARDUPILOT, "GUIDED"), (Flavour.ARDUPILOT, "LAND"), (Flavour.PX4, "OFFBOARD"),
     (Flavour.PX4, "AUTO.LAND"), (Flavour.PX4, "POSCTL")],
)
def test_heartbeat_mode_flavour_armed(flavour: Flavour, mode: str) -> None:
    v = Vehicle()
    state = VehicleState(3)
    changes = apply(state, v.heartbeat(flavour, mode, armed=True), 1.0)
    assert state.flavour is flavour and state.mode == mode and state.armed
    assert state.system_status == mavlink.MAV_STATE_ACTIVE
    assert [c.event for c in changes] == ["flavour", "mode_changed", "armed"]
    assert apply(state, v.heartbeat(flavour, mode, armed=True), 2.0) == []
    # A disarm nobody asked for, in the air as far as the link knows: believed from the
    # next HEARTBEAT with the vehicle's stream in between, not from one alone.
    assert apply(state, v.heartbeat(flavour, mode, armed=False), 3.0) == []
    assert state.armed
    _stream(v, state, 3.5)
    changes = apply(state, v.heartbeat(flavour, mode, armed=False), 4.0)
    assert [c.event for c in changes] == ["disarmed"]
    assert state.last_heard == 4.0 and state.first_heard == 1.0 and state.packets == 20


def _stream(v: Vehicle, state: VehicleState, t: float, n: int = 16) -> None:
    """What the vehicle streams between two reports (ATTITUDE here)."""
    for _ in range(n):
        apply(state, v(v.mav.attitude_encode(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)), t)


def test_companion_heartbeat_does_not_override_autopilot() -> None:
    v = Vehicle(comp=191)
    state = VehicleState(3)
    apply(state, v.heartbeat(Flavour.ARDUPILOT, "GUIDED", autopilot=mavlink.MAV_AUTOPILOT_INVALID),
          1.0)
    assert state.flavour is None and state.mode == "UNKNOWN" and state.last_heartbeat is None


def _geodetic(north: float, east: float, down: float) -> tuple[int, int, int]:
    """MAVLink lat, lon (1e-7 deg), alt (mm) of a point NED of the EKF origin below."""
    lat, lon, alt = pymap3d.ned2geodetic(north, east, down, 47.3977, 8.5455, 488.0)
    return round(float(lat) * 1e7), round(float(lon) * 1e7), round(float(alt) * 1000)


def test_telemetry_fields() -> None:
    v = Vehicle()
    m = v.mav
    s = VehicleState(3)
    lat, lon, alt = _geodetic(1.0, 2.0, -12.0)
    home = _geodetic(0.5, 0.5, 0.1)
    changes = []
    # Positions, battery and home are believed from reports that go on agreeing (the
    # first one alone could be anyone's): the vehicle reports each a few times.
    for k, t in enumerate((0.0, 0.3, 0.6, 0.9)):
        ms = 1000 + round(t * 1000)
        apply(s, v(m.local_position_ned_encode(ms, 1.0, 2.0, -12.0, 0.1, 0.2, -0.3)), t)
        apply(s, v(m.global_position_int_encode(ms, lat, lon, alt, 12_000,
                                                10, 20, -30, 9000)), t)
        apply(s, v(m.sys_status_encode(0, 0, 0, 0, 12600, 0, 87, 0, 0, 0, 0, 0, 0)), t)
        apply(s, v(m.gps_raw_int_encode(0, 3, 0, 0, 0, 0, 0, 0, 0, 14)), t)
        if k == 3:
            apply(s, v(m.gps_global_origin_encode(473977000, 85455000, 488_000)), t)
        changes = apply(s, v(m.home_position_encode(*home, 0.5, 0.5, 0.1, [1, 0, 0, 0],
                                                    0, 0, 0)), t)
    assert s.position_ned == (1.0, 2.0, -12.0)
    assert s.velocity_ned == pytest.approx((0.1, 0.2, -0.3))
    g = s.global_position
    assert g is not None and g.lat_deg == pytest.approx(lat / 1e7) and g.alt_m == alt / 1000
    assert g.relative_alt_m == 12.0 and g.vel_ned == (0.1, 0.2, -0.3) and g.heading_deg == 90
    assert (s.battery_remaining_pct, s.battery_voltage_v) == (87, 12.6)
    assert (s.gps_fix_type, s.gps_satellites) == (3, 14)
    assert s.ekf_origin is not None and s.ekf_origin.alt_m == 488.0
    assert s.home is not None and s.home.alt_m == pytest.approx(487.9)
    assert [c.event for c in changes] == ["home"]
    assert s.link_conflicts == 0
    # BATTERY_STATUS overrides (a jump of more than 5 points: from its second report);
    # "unknown" markers do not erase known values
    for t in (1.0, 2.0):
        apply(s, v(m.battery_status_encode(0, 0, 0, 0, [4000, 4000, 4000] + [65535] * 7,
                                           0, 0, 0, 55)), t)
        _stream(v, s, t)
    assert (s.battery_remaining_pct, s.battery_voltage_v) == (55, 12.0)
    apply(s, v(m.sys_status_encode(0, 0, 0, 0, 65535, 0, -1, 0, 0, 0, 0, 0, 0)), 3.0)
    assert (s.battery_remaining_pct, s.battery_voltage_v) == (55, 12.0)


def test_each_autopilots_wind_estimate_is_read_as_the_airs_velocity() -> None:
    v = Vehicle()
    s = VehicleState(3)
    # ArduPilot's WIND: from the west-south-west (240 deg), 10 m/s the whole vector's
    # length with 6 m/s of it vertical: the air moves 8 m/s to the east-north-east.
    apply(s, v(v.mav.wind_encode(240.0, 10.0, 6.0)), 1.0)
    assert s.wind_ned == pytest.approx((4.0, 6.928203, 6.0), abs=1e-5)
    assert s.wind_speed(2.0, 5.0) == pytest.approx(8.0, rel=1e-5)
    assert s.wind_speed(7.0, 5.0) is None  # stale
    # PX4's WIND_COV: the vector itself; NaN (no estimate yet) leaves it as it was.
    apply(s, v(v.mav.wind_cov_encode(0, 3.0, -4.0, 0.0, 0.1, 0.1, 10.0, 0.5, 0.5)), 3.0)
    assert s.wind_ned == (3.0, -4.0, 0.0) and s.wind_speed(3.0, 5.0) == 5.0
    apply(s, v(v.mav.wind_cov_encode(0, float("nan"), 0.0, 0.0, 0, 0, 0, 0, 0)), 4.0)
    apply(s, v(v.mav.wind_encode(0.0, 1e6, 0.0)), 4.0)  # not a wind: ignored
    assert s.wind_ned == (3.0, -4.0, 0.0) and s.wind_at == 3.0


def test_statustext_and_acks_are_kept() -> None:
    v = Vehicle()
    s = VehicleState(3)
    changes = apply(s, v(v.mav.statustext_encode(2, b"Arm: Need Position Estimate")), 5.0)
    assert changes[0].event == "statustext"
    assert s.last_statustext is not None and s.last_statustext.text == "Arm: Need Position Estimate"
    apply(s, v(v.mav.command_ack_encode(400, 4)), 5.0)
    assert s.acks[-1].result == 4


def _chunks(v: Vehicle, text: str, cid: int, empty_end: bool = True
            ) -> list[mavlink.MAVLink_message]:
    raw = text.encode()
    parts = [raw[i:i + 50] for i in range(0, len(raw), 50)]
    if empty_end and len(raw) % 50 == 0:
        parts.append(b"")  # ArduPilot ends a text that fills its chunks with an empty one
    return [v(v.mav.statustext_encode(4, p, cid, k)) for k, p in enumerate(parts)]


def test_chunked_statustext_is_reassembled_into_one_line() -> None:
    v = Vehicle()
    s = VehicleState(3)
    long = "PreArm: Check fence: " + "x" * 60 + " and then some more words."
    lines = []
    for m in _chunks(v, long, cid=7):
        lines += [c.fields["text"] for c in apply(s, m, 1.0) if c.event == "statustext"]
    assert lines == [long]
    exact = "y" * 100  # fills two chunks: ended by an empty third
    lines = [c.fields["text"] for m in _chunks(v, exact, cid=8) for c in apply(s, m, 2.0)
             if c.event == "statustext"]
    assert lines == [exact] and s.last_statustext is not None
    assert s.last_statustext.text == exact and s.text_chunks == {}


def test_chunked_statustext_with_a_lost_chunk_or_no_end_is_still_reported() -> None:
    v = Vehicle()
    s = VehicleState(3)
    first, _, third = _chunks(v, "a" * 50 + "b" * 50 + "the end", cid=3)
    apply(s, first, 1.0)
    changes = apply(s, third, 1.1)  # the middle chunk was lost on the way
    assert [c.fields["text"] for c in changes] == ["a" * 50 + " [...] the end"]
    # PX4 sends no empty chunk after a text that fills its chunks: the next text ends it.
    px4 = _chunks(v, "z" * 50, cid=4, empty_end=False)
    apply(s, px4[0], 2.0)
    changes = apply(s, v(v.mav.statustext_encode(6, b"next", 5, 0)), 2.1)
    assert [c.fields["text"] for c in changes] == ["z" * 50, "next"]
    # Or, when nothing follows, a second later.
    apply(s, _chunks(v, "w" * 50, cid=9, empty_end=False)[0], 3.0)
    changes = apply(s, v(v.mav.statustext_encode(6, b"plain")), 4.5)
    assert [c.fields["text"] for c in changes] == ["w" * 50 + " [...]", "plain"]


def test_sequence_gaps_give_loss_ratio() -> None:
    t = SequenceTracker()
    rng = np.random.default_rng(7)
    sent = 2000
    kept = rng.random(sent) > 0.1
    kept[0] = True
    for seq in np.flatnonzero(kept):
        t.update(1, int(seq) % 256)
    assert t.received == kept.sum()
    assert t.lost == sent - kept.sum() - (0 if kept[-1] else np.argmax(kept[::-1]))
    assert t.loss_ratio == pytest.approx(0.1, abs=0.02)


def test_sequence_wrap_duplicates_and_components() -> None:
    t = SequenceTracker()
    for seq in (250, 251, 255, 0, 2):  # wraps: lost 252, 253, 254, 1
        t.update(1, seq)
    assert t.lost == 4
    t.update(1, 2)  # duplicate
    t.update(1, 1)  # late
    assert t.lost == 3 and t.reordered == 2  # the late 1 was not lost after all
    t.update(2, 100)  # another component has its own counter
    assert t.lost == 3


def test_loss_seen_through_apply() -> None:
    v = Vehicle()
    s = VehicleState(3)
    for i in range(10):
        msg = v(v.mav.heartbeat_encode(2, 3, 0, 0, 3))
        if i % 2 == 0:
            apply(s, msg, float(i))
    assert s.quality.lost == 4 and s.loss_ratio == pytest.approx(4 / 9)


def test_timesync_offset_with_jitter_keeps_lowest_rtt_sample() -> None:
    rng = np.random.default_rng(42)
    est = TimesyncEstimator(window=16)
    true_offset = 123.456789  # vehicle booted long before our clock's zero
    now = 10.0
    for _ in range(40):
        ts1 = est.request(now)
        up = 0.002 + rng.exponential(0.010)  # queueing delays, asymmetric per leg
        down = 0.002 + rng.exponential(0.010)
        tc1 = round((now + up + true_offset) * NS)
        now += up + down
        assert est.receive(tc1, ts1, now) is not None
        now += 0.1
    assert est.offset_s == pytest.approx(true_offset, abs=0.004)
    best = est.best
    assert best is not None and best.rtt_ns == min(s.rtt_ns for s in est.samples)
    assert est.vehicle_time_s(now) == pytest.approx(now + true_offset, abs=0.004)


def test_timesync_exact_without_jitter_and_ignores_foreign_answers() -> None:
    est = TimesyncEstimator()
    ts1 = est.request(1.0)
    assert est.receive(5 * NS, 999, 1.02) is None  # not our request
    assert est.receive(0, ts1, 1.02) is None  # a request, not an answer
    sample = est.receive(round(6.01 * NS), ts1, 1.02)
    assert sample is not None
    assert sample.offset_ns == 5 * NS and sample.rtt_ns == round(0.02 * NS)
    assert est.receive(round(6.01 * NS), ts1, 1.03) is None  # duplicate answer
    assert answer(0, 77, 2.0) == (2 * NS, 77)
    assert answer(5, 77, 2.0) is None


def test_a_chunked_statustext_left_unfinished_is_reported_by_the_periodic_expiry() -> None:
    from groundctl.link.state import expire_chunks

    v = Vehicle()
    s = VehicleState(3)
    apply(s, _chunks(v, "q" * 50, cid=11, empty_end=False)[0], 1.0)  # PX4: nothing follows
    assert expire_chunks(s, 1.5) == []
    changes = expire_chunks(s, 2.1)
    assert [c.fields["text"] for c in changes] == ["q" * 50 + " [...]"] and s.text_chunks == {}
    # A plain text ends a pending chunked one first, in order.
    apply(s, _chunks(v, "r" * 50, cid=12, empty_end=False)[0], 3.0)
    changes = apply(s, v(v.mav.statustext_encode(6, b"plain")), 3.1)
    assert [c.fields["text"] for c in changes] == ["r" * 50 + " [...]", "plain"]
