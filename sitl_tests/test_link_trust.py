"""What the link believes: forged packets under a vehicle's own ids against its real stream.

A vehicle's autopilot streams as a real one does (HEARTBEAT 1 Hz, LOCAL_POSITION_NED
10 Hz, GLOBAL_POSITION_INT 5 Hz, SYS_STATUS 1 Hz, one sequence numbering); an
attacker sends packets with the same system and component id, either with a
numbering of its own or predicting the vehicle's next number (it can sniff).  The
state is fed as the link feeds it (:func:`apply`), so these tests are the security
issue's item 1 reproduced without a network.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import pymap3d
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.link.flavours import Flavour, encode_mode
from groundctl.link.state import StateChange, VehicleState, apply, expect
from groundctl.link.trust import (
    JUMP_CONFIRM_S,
    MAX_STEP,
    REORDER_S,
    MotionCheck,
    Sample,
    Seq,
    SequenceCheck,
)

ORIGIN = (47.3977, 8.5455, 488.0)


@dataclass
class Autopilot:
    """Packs what a vehicle (or someone posing as it) sends; decodes it as the link does."""

    sysid: int = 3
    comp: int = 1
    flavour: Flavour = Flavour.ARDUPILOT
    mode: str = "GUIDED"
    armed: bool = True
    pos: list[float] = field(default_factory=lambda: [0.0, 0.0, -10.0])
    vel: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    battery: int = 80
    origin: tuple[float, float, float] = ORIGIN
    first_seq: int = 0

    def __post_init__(self) -> None:
        self.mav = mavlink.MAVLink(None, srcSystem=self.sysid, srcComponent=self.comp)
        self.mav.seq = self.first_seq
        self.rx = mavlink.MAVLink(None)

    def __call__(self, msg: mavlink.MAVLink_message) -> mavlink.MAVLink_message:
        data = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        (out,) = self.rx.parse_buffer(data)
        return out

    def heartbeat(self, mode: str | None = None, armed: bool | None = None
                  ) -> mavlink.MAVLink_message:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.armed if armed is None else armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        return self(self.mav.heartbeat_encode(
            mavlink.MAV_TYPE_QUADROTOR, self.flavour.mav_autopilot, base,
            encode_mode(self.flavour, mode or self.mode), mavlink.MAV_STATE_ACTIVE))

    def local(self, t: float) -> mavlink.MAVLink_message:
        return self(self.mav.local_position_ned_encode(round(t * 1000), *self.pos, *self.vel))

    def global_(self, t: float) -> mavlink.MAVLink_message:
        lat, lon, alt = pymap3d.ned2geodetic(*self.pos, *self.origin)
        return self(self.mav.global_position_int_encode(
            round(t * 1000), round(float(lat) * 1e7), round(float(lon) * 1e7),
            round(float(alt) * 1000), round(-self.pos[2] * 1000), round(self.vel[0] * 100),
            round(self.vel[1] * 100), round(self.vel[2] * 100), 0))

    def sys_status(self, pct: int | None = None) -> mavlink.MAVLink_message:
        return self(self.mav.sys_status_encode(0, 0, 0, 0, 12600, 0,
                                               self.battery if pct is None else pct,
                                               0, 0, 0, 0, 0, 0))

    def gps_origin(self, origin: tuple[float, float, float] | None = None
                   ) -> mavlink.MAVLink_message:
        lat, lon, alt = origin or self.origin
        return self(self.mav.gps_global_origin_encode(round(lat * 1e7), round(lon * 1e7),
                                                      round(alt * 1000)))


@dataclass
class Flight:
    """A state fed by one autopilot's stream at 10 Hz of simulated time."""

    vehicle: Autopilot = field(default_factory=Autopilot)
    state: VehicleState = field(default_factory=lambda: VehicleState(3))
    t: float = 10.0
    tick: int = 0
    changes: list[StateChange] = field(default_factory=list)
    drop_next: bool = False
    drop_heartbeats: bool = False
    """The vehicle's own HEARTBEATs are lost on the way (its other packets arrive)."""
    fall: bool = False
    """The vehicle falls (motors stopped): gravity, until it reaches the ground."""
    seen: list[tuple[str, bool, float | None, float | None]] = field(default_factory=list)
    """(mode, armed, battery, north) believed after every packet."""

    def feed(self, msg: mavlink.MAVLink_message) -> list[StateChange]:
        got = apply(self.state, msg, self.t)
        self.changes += got
        s = self.state
        self.seen.append((s.mode, s.armed, s.battery_remaining_pct,
                          None if s.position_ned is None else s.position_ned[0]))
        return got

    def modes(self) -> set[str]:
        return {m for m, _, _, _ in self.seen}

    def ever_disarmed(self) -> bool:
        return not all(a for _, a, _, _ in self.seen)

    def fly(self, seconds: float) -> None:
        """The vehicle's own stream for ``seconds``: it moves at its velocity."""
        v = self.vehicle
        for _ in range(round(seconds * 10)):
            self.t = round(self.t + 0.1, 6)
            self.tick += 1
            if self.fall:
                v.vel[2] += 9.81 * 0.1
            v.pos = [p + u * 0.1 for p, u in zip(v.pos, v.vel, strict=True)]
            if v.pos[2] >= 0.0:
                v.pos[2], v.vel[2] = 0.0, 0.0  # the ground
            batch = [v.local(self.t)]
            if self.tick % 2 == 0:
                batch.append(v.global_(self.t))
            if self.tick % 10 == 0:
                batch += [v.heartbeat(), v.sys_status()]
            for msg in batch:
                if self.drop_next:
                    self.drop_next = False  # lost on the way
                    continue
                if self.drop_heartbeats and msg.get_type() == "HEARTBEAT":
                    continue
                self.feed(msg)

    def events(self, name: str) -> list[StateChange]:
        return [c for c in self.changes if c.event == name]


def _airborne() -> Flight:
    f = Flight()
    f.fly(3.0)
    assert f.state.mode == "GUIDED" and f.state.armed and f.state.link_conflicts == 0
    f.changes, f.seen = [], []
    return f


def _sniffer(f: Flight) -> Autopilot:
    """An attacker that predicts the vehicle's next sequence number."""
    a = Autopilot()
    a.mav.seq = f.vehicle.mav.seq
    return a


# -- item 1: forged reports ---------------------------------------------------------------


@pytest.mark.parametrize("sniffs", [False, True], ids=["own-numbering", "predicted-numbering"])
def test_one_forged_loiter_heartbeat_does_not_take_the_vehicle_out_of_the_show(
        sniffs: bool) -> None:
    f = _airborne()
    attacker = _sniffer(f) if sniffs else Autopilot(first_seq=200)
    f.feed(attacker.heartbeat(mode="LOITER"))
    f.fly(3.0)
    assert f.modes() == {"GUIDED"}  # at no moment did the link believe LOITER
    assert f.events("mode_changed") == [] and f.state.link_conflicts >= 1
    assert f.events("link_conflict")[0].fields["count"] == 1


def test_a_flood_of_forged_heartbeats_with_predicted_numbers_changes_nothing() -> None:
    f = _airborne()
    for _ in range(30):  # 20 Hz for 3 s, each just before the vehicle's next packet
        f.feed(_sniffer(f).heartbeat(mode="LOITER", armed=False))
        f.fly(0.1)
        f.feed(_sniffer(f).heartbeat(mode="LOITER", armed=False))
    assert f.modes() == {"GUIDED"} and not f.ever_disarmed()
    assert f.state.link_conflicts >= 30


@pytest.mark.parametrize("numbering", ["ahead", "behind", "predicted"])
def test_forged_disarmed_heartbeats_never_make_an_airborne_vehicle_landed(
        numbering: str) -> None:
    f = _airborne()  # the vehicle's numbering is at 50
    for _ in range(5):
        attacker = _sniffer(f) if numbering == "predicted" else \
            Autopilot(first_seq=90 if numbering == "ahead" else 10)
        f.feed(attacker.heartbeat(armed=False))
        f.fly(0.5)
    assert not f.ever_disarmed() and f.events("disarmed") == []
    # Numbered behind the vehicle or into its next numbers, each is a conflict at once.
    # Numbered ahead, each is held (a jittery link delivers bursts early) until the
    # vehicle's own numbering meets it: here the fifth copy came within a step of it and
    # the vehicle's own packet 90 then conflicted with it.
    assert f.state.link_conflicts >= (1 if numbering == "ahead" else 5)


def test_a_disarm_while_climbing_is_refuted_by_the_vehicles_own_climb() -> None:
    """The hardest forgery: the attacker's HEARTBEAT takes the number of a packet of the
    vehicle's that was lost, so the numbering cannot tell.  The vehicle climbs at 2 m/s,
    which no disarmed multirotor does: refuted before the next HEARTBEAT could confirm."""
    f = _airborne()
    f.vehicle.vel = [0.0, 0.0, -2.0]
    f.fly(0.5)
    f.feed(_sniffer(f).heartbeat(armed=False))
    f.drop_next = True  # the vehicle's own packet with that number never arrives
    f.fly(0.5)
    assert not f.ever_disarmed() and f.state.link_conflicts == 1
    assert "climbs at 2.0 m/s" in (f.state.last_conflict or "")
    f.feed(_sniffer(f).heartbeat(armed=False))  # a second one: nothing to confirm
    f.drop_next = True
    f.fly(2.0)
    assert not f.ever_disarmed() and f.events("disarmed") == []


def test_forged_disarms_with_the_vehicles_own_heartbeats_lost_are_refuted_by_its_hover(
        ) -> None:
    """Forged "disarmed" HEARTBEATs a second apart, numbered as the vehicle's lost packets,
    and none of the vehicle's own HEARTBEATs in between (lost on the radio, or dropped by a
    ground station whose socket overflowed while it was busy): two agreeing HEARTBEATs
    would confirm the disarm.  A disarmed multirotor falls; this one holds 10 m, so the
    claim is refuted (measured in a busy nine-vehicle dry-run, before: vehicle 5 was
    dropped from the show as crashed while it hovered)."""
    f = _airborne()
    f.drop_heartbeats = True
    for _ in range(4):
        f.feed(_sniffer(f).heartbeat(armed=False))
        f.drop_next = True
        f.fly(1.0)
    assert not f.ever_disarmed() and f.events("disarmed") == []
    assert "disarmed while it descends at 0.0 m/s, 10.0 m up" in (f.state.last_conflict or "")
    f.drop_heartbeats = False
    f.fly(2.0)
    assert f.state.armed and f.state.mode == "GUIDED"


def test_a_real_disarm_in_the_air_is_believed_from_its_second_heartbeat_as_it_falls() -> None:
    f = _airborne()
    f.vehicle.armed, f.fall = False, True  # a kill switch at 10 m
    heartbeats = 0
    while heartbeats < 2:
        heartbeats += f.tick % 10 == 9  # the next tick sends one
        f.fly(0.1)
    assert not f.state.armed and len(f.events("disarmed")) == 1
    assert not any("disarmed while" in c.fields["reason"] for c in f.events("link_conflict"))


def test_a_disarm_after_a_crash_is_believed_once_the_vehicle_lies_on_the_ground() -> None:
    f = _airborne()
    f.vehicle.vel = [0.0, 0.0, 3.0]  # comes down at 3 m/s, disarms lying there
    f.fly(4.0)
    f.vehicle.armed = False
    f.fly(2.0)
    assert not f.state.armed and f.state.link_conflicts == 0


@pytest.mark.parametrize("sniffs", [False, True], ids=["own-numbering", "predicted-numbering"])
def test_a_forged_ekf_origin_is_refused_and_the_real_one_believed(sniffs: bool) -> None:
    f = Flight()
    f.vehicle.armed, f.vehicle.mode = False, "STABILIZE"
    f.vehicle.pos = [2.0, -1.0, 0.0]  # on the ground, 2.2 m from where the EKF began
    f.fly(1.0)
    forged = (ORIGIN[0] + 0.0003, ORIGIN[1], ORIGIN[2] + 5.0)  # 33 m north, 5 m up
    attacker = _sniffer(f) if sniffs else Autopilot(first_seq=150)
    f.feed(attacker.gps_origin(forged))  # before the real one
    f.fly(0.5)
    assert f.state.ekf_origin is None and f.state.link_conflicts >= 1
    f.feed(f.vehicle.gps_origin())
    assert f.state.ekf_origin is not None
    assert (f.state.ekf_origin.lat_deg, f.state.ekf_origin.alt_m) == (ORIGIN[0], ORIGIN[2])
    f.feed(_sniffer(f).gps_origin(forged))  # and after it
    f.fly(0.5)
    assert f.state.ekf_origin.lat_deg == ORIGIN[0] and len(f.events("ekf_origin")) == 1


def _home_msg(a: Autopilot, ned: tuple[float, float, float]) -> mavlink.MAVLink_message:
    lat, lon, alt = pymap3d.ned2geodetic(*ned, *ORIGIN)
    return a(a.mav.home_position_encode(round(float(lat) * 1e7), round(float(lon) * 1e7),
                                        round(float(alt) * 1000), *ned, [1.0, 0.0, 0.0, 0.0],
                                        0.0, 0.0, 0.0))


def test_a_forged_home_is_refused_the_real_one_under_the_vehicle_believed_at_once() -> None:
    f = Flight()
    f.vehicle.armed, f.vehicle.mode = False, "STABILIZE"
    f.vehicle.pos = [1.0, 1.0, 0.0]
    f.fly(1.0)
    f.feed(f.vehicle.gps_origin())
    assert f.state.ekf_origin is not None
    for _ in range(3):  # 30 m away (PX4 would take off from its altitude), consistent
        f.feed(_home_msg(_sniffer(f), (30.0, 0.0, -8.0)))  # with the origin, twice and more
        f.fly(1.0)
    assert f.state.home is None and f.state.link_conflicts >= 3
    f.feed(_home_msg(f.vehicle, (1.0, 1.0, 0.0)))
    assert f.state.home is not None and f.state.home.alt_m == pytest.approx(ORIGIN[2])


def test_a_second_autopilot_component_is_a_conflict_and_its_telemetry_is_ignored() -> None:
    f = _airborne()
    other = Autopilot(comp=42)
    f.feed(other.heartbeat(mode="LAND", armed=False))
    f.feed(other.sys_status(pct=3))
    f.fly(1.0)
    f.feed(other.sys_status(pct=3))
    f.fly(1.0)
    assert f.modes() == {"GUIDED"} and not f.ever_disarmed()
    assert {b for _, _, b, _ in f.seen} == {80}
    assert "second autopilot (component 42)" in (f.events("link_conflict")[0].fields["reason"])


def test_a_forged_battery_report_is_refused_a_real_drop_believed_from_its_second_report(
        ) -> None:
    f = _airborne()
    f.feed(_sniffer(f).sys_status(pct=4))
    f.fly(2.0)
    assert {b for _, _, b, _ in f.seen} == {80} and f.state.link_conflicts >= 1
    f.vehicle.battery = 9  # a failing pack: the vehicle's own reports from now on
    f.fly(1.0)
    assert f.state.battery_remaining_pct == 80
    f.fly(1.0)
    assert f.state.battery_remaining_pct == 9


def test_a_forged_position_is_refused_a_real_jump_believed_once_the_stream_goes_on() -> None:
    f = _airborne()
    attacker = _sniffer(f)
    attacker.pos = [30.0, 0.0, -10.0]
    f.feed(attacker.local(f.t + 0.05))
    f.fly(1.0)
    assert all(x is not None and abs(x) < 0.01 for _, _, _, x in f.seen)
    assert f.state.link_conflicts >= 1
    conflicts = f.state.link_conflicts
    # An EKF reset / GPS glitch: the vehicle's own stream jumps 5 m and goes on from there.
    f.vehicle.pos[0] += 5.0
    f.fly(0.1)
    assert f.state.position_ned is not None
    assert abs(f.state.position_ned[0]) < 0.01  # not yet: one sample could be anyone's
    f.fly(JUMP_CONFIRM_S + 0.1)
    assert f.state.position_ned is not None and f.state.position_ned[0] == pytest.approx(5.0)
    assert f.state.link_conflicts == conflicts


# -- genuine changes stay prompt ----------------------------------------------------------


def test_a_mode_change_nobody_asked_for_is_believed_at_the_next_heartbeat() -> None:
    f = _airborne()
    f.fly(0.5)  # half-way between two heartbeats
    f.vehicle.mode = "LAND"  # a battery failsafe
    f.fly(0.5)  # the next heartbeat: one report, not believed yet
    assert f.state.mode == "GUIDED"
    f.fly(1.0)  # the one after confirms it
    assert f.state.mode == "LAND" and f.state.link_conflicts == 0
    assert [c.fields for c in f.events("mode_changed")] == [{"old": "GUIDED", "new": "LAND"}]


def test_what_the_executor_asked_for_is_believed_without_waiting_for_a_second_heartbeat(
        ) -> None:
    f = Flight()
    f.vehicle.armed, f.vehicle.mode = False, "STABILIZE"
    f.vehicle.pos = [0.0, 0.0, 0.0]
    f.fly(1.0)
    expect(f.state, f.t, mode="GUIDED")
    f.feed(_sniffer(f).heartbeat(mode="GUIDED"))  # a forged "yes", before the vehicle's
    f.fly(0.9)
    assert f.state.mode == "STABILIZE" and f.state.link_conflicts == 1
    f.vehicle.mode = "GUIDED"
    f.fly(0.1)  # its HEARTBEAT
    assert f.state.mode == "STABILIZE"
    f.fly(0.3)  # and a few more packets of its own: 0.3 s, not the next HEARTBEAT's 1 s
    assert f.state.mode == "GUIDED"
    expect(f.state, f.t, armed=True)
    f.fly(0.6)
    f.vehicle.armed = True
    f.fly(0.4)
    assert f.state.armed
    # Expected LAND, but LOITER was not asked for: that one waits (and is forged here).
    expect(f.state, f.t, mode="LAND")
    f.feed(_sniffer(f).heartbeat(mode="LOITER"))
    f.fly(1.0)
    assert f.state.mode == "GUIDED" and f.state.link_conflicts == 2


def test_a_landing_ends_with_its_first_disarmed_heartbeat_on_the_ground() -> None:
    f = _airborne()
    expect(f.state, f.t, mode="LAND")
    f.vehicle.mode = "LAND"
    f.vehicle.vel = [0.0, 0.0, 1.0]
    f.fly(10.5)  # down at 1 m/s, standing since
    assert f.state.mode == "LAND" and f.state.armed
    f.vehicle.armed = False  # the autopilot disarms after touching down
    f.fly(1.0)
    assert not f.state.armed and len(f.events("disarmed")) == 1
    assert f.state.link_conflicts == 0


def test_a_disarm_on_the_ground_outside_a_landing_mode_needs_the_next_heartbeat() -> None:
    f = Flight()
    f.vehicle.pos, f.vehicle.mode = [0.0, 0.0, 0.0], "GUIDED"
    f.fly(2.0)
    f.vehicle.armed = False  # the autopilot's disarm delay: armed, never took off
    f.fly(1.0)
    assert f.state.armed
    f.fly(1.0)
    assert not f.state.armed


# -- the pieces ---------------------------------------------------------------------------


def test_sequence_numbers_wrap_lose_reorder_and_duplicate_without_conflict() -> None:
    c = SequenceCheck()
    verdicts = [c.check(s, s) for s in (250, 251, 253, 255, 0, 1, 3, 2, 252)]
    assert verdicts == [Seq.FIRST, Seq.NEXT, Seq.NEXT, Seq.NEXT, Seq.NEXT, Seq.NEXT, Seq.NEXT,
                        Seq.LATE, Seq.LATE]
    assert c.check(3, 3) is Seq.DUPLICATE  # the same bytes again
    assert c.check(3, 999) is Seq.CONFLICT  # a different packet under that number
    assert "two different packets numbered 3" in c.reason
    assert c.check(3, 3) is Seq.CONFLICT  # and that number stays contested


@pytest.mark.parametrize("forged", [100 + MAX_STEP + 1, 100 + 100, 100 - 70],
                         ids=["far-ahead", "farther-ahead", "far-behind"])
def test_a_packet_far_from_the_numbering_is_held_and_blamed_when_it_does_not_fit(
        forged: int) -> None:
    # Held, never acted on.  Behind the numbering it is blamed at the next packet; ahead
    # of it (a jittery link may have sent it early), when the vehicle's own packet of its
    # number comes.
    c = SequenceCheck()
    for s in range(40, 101):
        c.check(s, s, "LOCAL_POSITION_NED", at=s * 0.05)
    assert c.check(forged % 256, -1, "HEARTBEAT", at=5.06) is Seq.HELD  # not acted on
    assert c.blame == []
    s = 101
    while not c.blame:
        assert s <= max(forged, 101)
        assert c.check(s % 256, s % 256, "LOCAL_POSITION_NED", at=5.07 + (s - 101) * 0.01) \
            is Seq.NEXT
        s += 1
    [(why, kinds)] = c.blame
    assert s - 1 == max(forged, 101)  # blamed with the packet that showed it
    assert (f"numbered {forged % 256} does not fit" in why if forged < 100
            else f"two different packets numbered {forged % 256}" in why)
    assert kinds == {"HEARTBEAT"}


def test_a_burst_the_link_reordered_is_no_conflict() -> None:
    # An autopilot's burst (parameters, a fence) through 50 ms of jitter: packets arrive
    # up to 30 numbers early.  Held until the numbering gets there, then taken as the
    # vehicle's own: no conflict (the simulator's jittery link made 185 a flight).
    c = SequenceCheck()
    for s in range(10, 40):
        c.check(s, s, "PARAM_VALUE", at=s * 0.001)
    order = [40, 41, 70, 42, 69, 43, 44, 60, *range(45, 60), *range(61, 69), 71, 72]
    verdicts = [c.check(s, s, "PARAM_VALUE", at=0.05 + k * 0.002) for k, s in enumerate(order)]
    assert Seq.CONFLICT not in verdicts and Seq.RESTART not in verdicts
    assert verdicts.count(Seq.HELD) == 3 and c.blame == [] and c.held == []
    assert c.newest == 72


def test_a_forged_jump_ahead_is_met_by_the_vehicles_own_number() -> None:
    c = SequenceCheck()
    c.check(100, 100)
    assert c.check(100 + MAX_STEP, -1, "HEARTBEAT") is Seq.NEXT  # the forger's: it fits
    late = [c.check(s, s, "LOCAL_POSITION_NED") for s in range(101, 100 + MAX_STEP)]
    assert late == [Seq.LATE] * (MAX_STEP - 1)  # the vehicle's own, filling in behind it
    assert c.check(100 + MAX_STEP, 0, "LOCAL_POSITION_NED") is Seq.CONFLICT
    assert c.suspects == {"HEARTBEAT", "LOCAL_POSITION_NED"}


def test_forged_packets_numbered_into_the_vehicles_past_never_pass_as_reordering() -> None:
    """A conflict must not make the numbering forget what the vehicle sent: the forger
    would then pass packets numbered into that past as late ones."""
    c = SequenceCheck()
    for s in range(0, 50):
        c.check(s, s)
    c.check(49, -1)  # a conflict
    assert [c.check(s, -s) for s in range(30, 49)] == [Seq.CONFLICT] * 19


def test_a_reboot_restarts_the_numbering_silently_or_with_one_conflict() -> None:
    c = SequenceCheck()
    for s in range(20, 60):
        c.check(s, s, at=s * 0.05)
    # Back after a silence of its own (it rebooted): wherever the numbering starts.
    assert [c.check(s, -s, at=10.0 + s * 0.05) for s in range(5)] == [Seq.NEXT] * 5
    # Without a silence: held while it might be a burst the link reordered; once the
    # stream has gone on from it for REORDER_S with the old numbering not catching up,
    # a new numbering.
    assert c.check(200, 200, at=10.3) is Seq.HELD
    assert c.check(201, 201, at=10.35) is Seq.HELD
    assert c.check(202, 202, at=10.3 + REORDER_S) is Seq.RESTART
    assert c.check(203, 203, at=10.4 + REORDER_S) is Seq.NEXT
    assert c.blame == [] and c.held == []


def test_a_slow_forged_stream_beside_the_vehicles_own_never_restarts_the_numbering() -> None:
    # A forger 70 numbers ahead, one packet every 0.2 s, while the vehicle streams at
    # 100 packets a second: held, blamed once the numbering shows they do not fit, never
    # taken as a new numbering (RESTART) and never acted on.
    c = SequenceCheck()
    for own in range(20):
        c.check(own, own, "LOCAL_POSITION_NED", at=own * 0.01)
    t, own, forged, verdicts = 0.2, 19, 19 + 70, []
    for _ in range(6):
        verdicts.append(c.check(forged % 256, -forged, "HEARTBEAT", at=t))
        forged += 1
        for _ in range(20):
            own += 1
            t += 0.01
            assert c.check(own % 256, own % 256, "LOCAL_POSITION_NED", at=t) is Seq.NEXT
    # Held while ahead, a conflict once the vehicle's own numbering has passed its number.
    assert set(verdicts) <= {Seq.HELD, Seq.CONFLICT} and Seq.HELD in verdicts, verdicts


@pytest.mark.parametrize("ahead", [20, 60, 127])
def test_a_forgers_numbering_is_not_counted_as_the_vehicles_loss(ahead: int) -> None:
    # Forged EKF origins in pre-flight, numbered by the forger's own codec (``ahead`` of
    # the vehicle's, beyond MAX_STEP), one every 0.3 s beside the vehicle's stream:
    # counted as gaps in the vehicle's numbering, they read as 33-64 % loss here and as
    # 36-46 % in the spoofing dry-run, failing every vehicle's link check.  Loss is the
    # vehicle's own numbering's.
    f = Flight()
    f.vehicle.armed, f.vehicle.mode = False, "STABILIZE"
    f.vehicle.pos = [0.0, 0.0, 0.0]
    f.fly(1.0)
    attacker = Autopilot(first_seq=(f.vehicle.mav.seq + ahead) % 256)
    forged = (ORIGIN[0] + 0.0005, ORIGIN[1], ORIGIN[2])
    for _ in range(20):
        f.feed(attacker.gps_origin(forged))
        attacker.mav.seq = (attacker.mav.seq + 7) % 256
        f.fly(0.3)
    assert f.state.link_conflicts >= 1 and f.state.ekf_origin is None
    assert f.state.quality.lost == 0 and f.state.loss_ratio == 0.0
    # A real loss still counts, and so does a packet the numbering reaches after it
    # arrived early (a reordered burst): no loss for it.
    f.drop_next = True
    f.fly(0.5)
    assert f.state.quality.lost == 1
    c, state = f.vehicle, f.state
    received = state.quality.received
    early = [c.local(f.t) for _ in range(MAX_STEP + 3)]  # 15 packets
    for msg in [early[-1], *early[:-1]]:  # the last one first: far ahead, held
        f.feed(msg)
    f.feed(c.local(f.t))  # and the next: the numbering has passed the early one
    # All 16 counted (the early one once the numbering reached it), none lost.
    assert state.quality.lost == 1 and state.quality.received == received + 16, state.quality


def test_a_new_numbering_starts_the_loss_count_afresh() -> None:
    # A reboot without a silence: the numbering goes on from held packets (RESTART).
    # The jump between the two numberings is not a loss.
    f = Flight()
    f.fly(2.0)
    received, packets = f.state.quality.received, f.state.packets
    f.vehicle.mav.seq = (f.vehicle.mav.seq + 100) % 256
    f.fly(1.0)
    assert f.state.quality.restarts == 1 and f.state.quality.lost == 0
    # Every packet of the new numbering counted, the ones held before the restart too.
    assert f.state.quality.received - received == f.state.packets - packets, f.state.quality


def _s(t: float, x: float, vx: float = 0.0, at: float | None = None) -> Sample:
    return Sample(t, (x, 0.0, -5.0), (vx, 0.0, 0.0), t if at is None else at)


def test_motion_follows_velocity_refuses_a_lone_sample_and_believes_a_continued_jump() -> None:
    m = MotionCheck()
    # The first track too is believed once it has gone on for JUMP_CONFIRM_S: a forged
    # first sample (before the vehicle streams) forms a run of its own that goes nowhere.
    assert m.offer(_s(0.5, 40.0, 0.0)) == ([], None)
    assert m.offer(_s(1.0, 0.0, 2.0)) == ([], None)
    assert m.offer(_s(1.1, 0.2, 2.0)) == ([], None)
    got, conflict = m.offer(_s(1.3, 0.6, 2.0))
    assert [s.t for s in got] == [1.0, 1.1, 1.3] and conflict is None
    assert m.offer(_s(1.35, 9.0, 2.0)) == ([], None)  # a forged sample: held
    got, conflict = m.offer(_s(1.4, 0.8, 2.0))  # the real one goes on: it was not its
    assert got == [_s(1.4, 0.8, 2.0)] and conflict is not None and "went on" in conflict
    # From the future: the vehicle's clock cannot run ahead of ours by 10 s.
    assert m.offer(_s(11.5, 1.0, 2.0, at=1.5)) == ([], None)
    assert m.offer(_s(1.6, 1.2, 2.0))[1] is not None
    # A reboot: its clock starts again, and the stream goes on from there.
    assert m.offer(_s(0.1, 1.2, 0.0, at=1.7)) == ([], None)
    assert m.offer(_s(0.2, 1.2, 0.0, at=1.8)) == ([], None)
    got, conflict = m.offer(_s(0.3, 1.2, 0.0, at=2.0))
    assert [s.t for s in got] == [0.1, 0.2, 0.3] and conflict is None


def test_random_forged_samples_do_not_keep_a_real_track_from_being_believed() -> None:
    rng = np.random.default_rng(5)
    m = MotionCheck()
    believed = []
    for k in range(10):
        t = 1.0 + 0.1 * k
        got, _ = m.offer(_s(t, 0.2 * k, 2.0))
        believed += got
        m.offer(_s(t + 0.05, float(rng.normal(0, 30)), float(rng.normal(0, 5))))
    assert believed and all(s.pos[0] == pytest.approx(2.0 * (s.t - 1.0)) for s in believed)


@pytest.mark.parametrize("rate_hz", [10.0, 5.0, 4.0, 2.0])
@pytest.mark.parametrize("height_m", [3.0, 8.0, 10.0, 20.0])
def test_a_fall_that_ends_on_the_ground_is_no_second_sender(rate_hz: float,
                                                            height_m: float) -> None:
    """A drone whose motors stop falls and stops dead on the ground, faster than any
    manoeuvre: the first sample on the ground does not follow the fall, the next fits
    both it and the fall.  That is one vehicle, not two senders (before: "position
    samples 0.4 m off the track, which went on (another sender)" on a motor failure)."""
    g = 9.81
    impact = math.sqrt(2.0 * height_m / g)
    m = MotionCheck()
    believed: list[Sample] = []
    for k in range(int(4.0 * rate_hz)):
        t = 1.0 + k / rate_hz
        fall = t - 1.0
        z, vz = (-height_m + 0.5 * g * fall * fall, g * fall) if fall < impact else (0.0, 0.0)
        got, conflict = m.offer(Sample(t, (0.0, 0.0, z), (0.0, 0.0, vz), t))
        assert conflict is None, (t, conflict)
        believed += got
    assert m.ref is not None and m.ref.pos == (0.0, 0.0, 0.0)  # believed down
    assert not m.chains  # nothing of the fall left waiting to be believed later
    assert all(a.t < b.t for a, b in itertools.pairwise(believed))
