"""Wind as real autopilots ride it: the line and a position hold in SITL's winds.

Real ArduCopter SITL (V4.8.0-dev), in a constant 8 m/s wind with turbulence 2
(SIM_WIND_SPD 8, SIM_WIND_T 1, SIM_WIND_TURB 2), flew the 10 m line of
test_sim_calibration.py at RMS 0.199 m (max 0.343 m) and moved 0.17 m in the
4 s after its setpoints stopped; in 12 m/s with SITL's default height profile
(SIM_WIND_T 0: 12 sqrt(5/60) = 3.5 m/s at 5 m) its 20 s position hold stayed
within 0.12 m.  SITL's wind blows north (SIM_WIND_DIR 180), along the line;
the 12 m/s hold is flown with turbulence 2 as well.

A hovering ArduCopter SITL in a step gust from the west for 4 s (SIM_WIND_T 1,
benchmarks/bench_gust.py) was carried 1.24 m by 9 m/s and, past its lean, 11.3 m by
15 m/s.  The simulator has to reproduce the gusts within 25 % (the one at 15 m/s: more
than 10 m), the hold and the calm line (test_sim_calibration.py) as well, and its PX4
flavour, whose controller has the same structure, has to hold too (no metres of drift).
Its line in the steady 8 m/s is flown worse than SITL's (RMS 0.28 against 0.199 m): the
airframe drag that matches SITL's gusts costs more along a line into the wind than SITL
shows, a gap on the cautious side, held here between 1x and 2x.

Over real UDP on loopback, on a ManualClock: a few seconds of wall time per flight.
benchmarks/bench_wind.py prints the whole table.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from sim_fixtures import manual_fleet
from test_sim_calibration import (
    AP,
    PX4,
    drift,
    fly_line,
    hold_excursion,
    stream_hold,
    takeoff,
    within,
)

from groundctl.link.flavours import Flavour
from groundctl.sim.config import ARDUPILOT_DYNAMICS, PX4_DYNAMICS, Wind, wind_from
from groundctl.sim.physics import CTRL_TRACK, FleetPhysics

#: SITL's winds of the measurements.
CALM = Wind()
WIND_8 = Wind.sitl(8.0, turbulence=2.0, wind_type=1)
WIND_12_PROFILE = Wind.sitl(12.0, turbulence=2.0, wind_type=0)

#: ArduCopter V4.8.0-dev SITL hovering at 5 m, a step gust from the west for 4 s: speed
#: (m/s) -> largest distance from where it hovered (m).
SITL_GUSTS = {9.0: 1.24, 15.0: 11.3}
#: ArduCopter V4.8.0-dev SITL in WIND_8: line RMS, max; drift in the 4 s after the line.
SITL_LINE_8 = (0.199, 0.343)
SITL_DRIFT_8 = 0.17
#: ... and its 20 s hold in WIND_12_PROFILE stayed within this (m).
SITL_HOLD_12 = 0.12

#: Hover time before the hold is measured (the integrator has learnt the wind), s.
SETTLE_S = 10.0
SEEDS = (0, 1, 2)


@dataclass(frozen=True)
class WindFigures:
    """One flight in one wind."""

    hold_max: float
    """Largest horizontal excursion over a 20 s position hold, m."""
    line_rms: float
    """The line's RMS tracking error, m."""
    line_max: float
    """The line's largest tracking error, m."""
    drift_4s: float
    """How far the vehicle moved in the 4 s after the line's last setpoint, m."""


def fly_in_wind(flavour: Flavour, wind: Wind, seed: int) -> WindFigures:
    """Take off, settle, hold 20 s, fly the line, measure the drift after it."""
    with manual_fleet(1, flavour=flavour, wind=wind, seed=seed) as (fleet, peer):
        takeoff(fleet, peer, flavour)
        stream_hold(fleet, peer, flavour, SETTLE_S, (0.0, 0.0, -5.0))
        hold = hold_excursion(fleet, peer, flavour)
        rms, worst, end = fly_line(fleet, peer)
        moved = drift(fleet, peer, flavour, end, wait=0.0)
    return WindFigures(hold, rms, worst, moved)


def mean_figures(flavour: Flavour, wind: Wind, seeds: tuple[int, ...] = SEEDS
                 ) -> WindFigures:
    """Means over ``seeds`` (the hold: the largest)."""
    runs = [fly_in_wind(flavour, wind, s) for s in seeds]
    return WindFigures(
        hold_max=max(r.hold_max for r in runs),
        line_rms=float(np.mean([r.line_rms for r in runs])),
        line_max=float(np.mean([r.line_max for r in runs])),
        drift_4s=float(np.mean([r.drift_4s for r in runs])))


def test_wind_profile_and_turbulence_follow_sitl() -> None:
    w = Wind.sitl(12.0, from_deg=180.0, turbulence=2.0)
    assert np.allclose(w.mean, (0.0, 12.0, 0.0))  # from the south: the air moves north
    with manual_fleet(1, wind=w) as (fleet, _peer):
        ph = fleet.physics
        ph.pos[0, 2] = ph.ground_z[0] + 5.0
        assert np.allclose(ph.wind_at()[0], (0.0, 12.0 * np.sqrt(5.0 / 60.0), 0.0))
        ph.pos[0, 2] = ph.ground_z[0] + 80.0
        assert np.allclose(ph.wind_at()[0], (0.0, 12.0, 0.0))
        ph.pos[0, 2] = ph.ground_z[0]
        fleet.step(2.0)  # on the ground: no turbulence
        assert not ph.turbulence.any()
    with pytest.raises(ValueError, match="turbulence"):
        Wind(turbulence=-1.0)


def test_only_ardupilot_advances_its_target_between_setpoints() -> None:
    # GUIDED moves a position + velocity (+ acceleration) target on every loop until
    # the next message; PX4's mc_pos_control flies each trajectory setpoint as it is.
    for dynamics, advances in ((ARDUPILOT_DYNAMICS, True), (PX4_DYNAMICS, False)):
        ph = FleetPhysics(np.zeros((1, 3)), dynamics, np.random.default_rng(0))
        ph.mode[:] = CTRL_TRACK
        ph.set_target(0, np.array([0.0, 0.0, 5.0]), np.array([1.0, 0.0, 0.0]),
                      np.array([0.5, 0.0, 0.0]))
        for _ in range(50):
            ph.step(0.02)
        expected = (1.0 + 0.25, 1.5) if advances else (0.0, 1.0)
        assert np.allclose((ph.tgt_pos[0, 0], ph.tgt_vel[0, 0]), expected), dynamics


def gust_carry(speed: float, seconds: float = 4.0, watch: float = 20.0) -> float:
    """Largest horizontal distance (LOCAL_POSITION_NED) from where a hovering ArduPilot
    vehicle was, after a step gust of ``speed`` m/s from the west for ``seconds``."""
    with manual_fleet(1, flavour=AP) as (fleet, peer):
        takeoff(fleet, peer, AP)
        stream_hold(fleet, peer, AP, SETTLE_S, (0.0, 0.0, -5.0))
        peer.poll()
        here = peer.all("LOCAL_POSITION_NED", 1)[-1]
        fleet.gust(wind_from(speed, 270.0), seconds, sysid=1, at=fleet.time)
        peer.clear()
        stream_hold(fleet, peer, AP, watch, (0.0, 0.0, -5.0))
        peer.poll()
        return max(float(np.hypot(m.x - here.x, m.y - here.y))
                   for m in peer.all("LOCAL_POSITION_NED", 1))


def test_a_step_gust_carries_ardupilot_as_far_as_it_carries_sitl() -> None:
    assert within(gust_carry(9.0), SITL_GUSTS[9.0])
    assert gust_carry(15.0) > 10.0  # beyond the airframe's lean: blown away


def test_ardupilot_rides_8_m_s_with_turbulence_no_better_than_sitl() -> None:
    f = mean_figures(AP, WIND_8)
    # The drift in 4 s at most 2.5 x, the line 2 x: the simulated turbulence is on the
    # cautious side (its line 1.4 x SITL's), and its drift was already 1.98 x SITL's
    # (0.337 m) before the airframe's own wander (session 38,
    # ARDUPILOT_DYNAMICS.airframe_noise) added its 5 mm.
    for name, value, sitl, most in (("line RMS", f.line_rms, SITL_LINE_8[0], 2.0),
                                    ("line max", f.line_max, SITL_LINE_8[1], 2.0),
                                    ("drift in 4 s", f.drift_4s, SITL_DRIFT_8, 2.5)):
        assert sitl <= value <= most * sitl, f"{name} {value:.3f} m against SITL's {sitl} m"
    assert f.hold_max < 0.15, f"hold {f.hold_max:.3f} m"


def test_ardupilot_holds_in_12_m_s_scaled_near_the_ground() -> None:
    f = mean_figures(AP, WIND_12_PROFILE)
    assert f.hold_max <= SITL_HOLD_12 * 1.25, f"hold {f.hold_max:.3f} m"


@pytest.mark.parametrize("wind", [WIND_8, WIND_12_PROFILE], ids=["8", "12-profile"])
def test_px4_holds_station_too(wind: Wind) -> None:
    f = mean_figures(PX4, wind, seeds=(0,))
    assert f.hold_max < 0.15, f"hold {f.hold_max:.3f} m"
    # (In 8 m/s the line costs it about 0.38 / 0.62 m, the same airframe drag as
    # ArduPilot's against a controller without ArduCopter's input shaping.)
    assert f.line_rms < 0.5 and f.line_max < 0.8, f"line {f.line_rms:.3f} / {f.line_max:.3f}"
    assert f.drift_4s < 0.4, f"drift {f.drift_4s:.3f} m in 4 s"


def test_a_steady_gale_beyond_the_tilt_limit_blows_the_vehicle_away() -> None:
    # 30 m/s needs more lean than ANGLE_MAX allows: the vehicle cannot hold (and
    # the integrator, limited at the tilt authority, does not wind up past it).
    gale = Wind(mean=(0.0, 30.0, 0.0))
    with manual_fleet(1, wind=gale) as (fleet, peer):
        takeoff(fleet, peer)
        assert fleet.state(1).position[1] > 5.0
        vint = fleet.physics._vint[0, :2]
        assert np.linalg.norm(vint) <= fleet.physics.dyn.vel_imax + 1e-9


def test_gusts_are_one_field_neighbours_meet_nearly_the_same_gust() -> None:
    """``gust_std`` gusts are a wind field (GustField): each axis has the asked standard
    deviation at any point, two points 1.7 m apart see nearly the same gust, points
    tens of metres apart different ones, and at a point it lasts about GUST_TAU."""
    from groundctl.sim.physics import GUST_TAU, GustField

    field = GustField(2.0, 12.0, GUST_TAU, np.random.default_rng(1))
    pts = np.array([[0.0, 0.0, 10.0], [1.7, 0.0, 10.0], [0.0, 40.0, 10.0]])
    g = np.array([field.at(pts, t) for t in np.arange(0.0, 4000.0, 0.5)])  # (T, 3, 3)
    assert np.allclose(g[:, 0].std(axis=0), 2.0, rtol=0.1)
    rel = (g[:, 0] - g[:, 1]).std(axis=0)
    assert np.all(rel < 0.4)  # independent gusts would differ by 2 sqrt(2) = 2.8 m/s
    far = np.corrcoef(g[:, 0, 0], g[:, 2, 0])[0, 1]
    assert abs(far) < 0.3
    lag = int(GUST_TAU / 0.5)
    assert 0.4 < np.corrcoef(g[:-lag, 0, 0], g[lag:, 0, 0])[0, 1] < 0.8  # exp(-1/2) = 0.61


def test_a_fleet_in_gusts_gets_its_gusts_from_the_field() -> None:
    homes = np.array([[0.0, 0.0, 0.0], [1.7, 0.0, 0.0]])
    ph = FleetPhysics(homes, ARDUPILOT_DYNAMICS, np.random.default_rng(3),
                      wind=(6.0, 0.0, 0.0), gust_std=2.0)
    assert ph.gust_field is not None and ph.gust_field.length == pytest.approx(12.0)
    expected = ph.gust_field.at(ph.pos.copy(), ph.t)
    ph.step(0.01)
    assert np.allclose(ph.gust, expected)
    calm = FleetPhysics(homes, ARDUPILOT_DYNAMICS, np.random.default_rng(3))
    assert calm.gust_field is None
