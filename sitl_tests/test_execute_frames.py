"""Show frame <-> geodetic <-> per-vehicle NED conversions."""

from __future__ import annotations

import numpy as np
import pytest
from test_execute_support import ORIGIN, geo_offset, make_vehicle

from groundctl.execute.frames import (
    geodetic_to_show,
    ned_to_show,
    ned_vel_to_show,
    show_positions,
    show_to_enu,
    show_to_geodetic,
    show_to_ned,
    show_vel_to_ned,
)
from groundctl.show.model import GeoOrigin

POINTS = np.array([[0.0, 0.0, 0.0], [10.0, -20.0, 30.0], [-150.0, 220.0, 80.0],
                   [400.0, 400.0, 120.0]])


@pytest.mark.parametrize("heading", [0.0, 37.0, 90.0, 271.5])
def test_show_geodetic_round_trip_within_a_millimetre(heading: float) -> None:
    origin = GeoOrigin(ORIGIN.lat, ORIGIN.lon, ORIGIN.alt, heading)
    lat, lon, alt = show_to_geodetic(origin, POINTS)
    back = geodetic_to_show(origin, lat, lon, alt)
    np.testing.assert_allclose(back, POINTS, atol=1e-3)


@pytest.mark.parametrize("heading", [0.0, 90.0, 200.0])
def test_show_ned_round_trip_with_a_distant_ekf_origin(heading: float) -> None:
    origin = GeoOrigin(ORIGIN.lat, ORIGIN.lon, ORIGIN.alt, heading)
    ekf = geo_offset(ORIGIN, 120.0, -80.0, 3.0)
    ned = show_to_ned(origin, ekf, POINTS)
    np.testing.assert_allclose(ned_to_show(origin, ekf, ned), POINTS, atol=1e-3)


@pytest.mark.parametrize("heading", [0.0, 37.0, 271.5])
def test_the_rigid_motion_per_origin_matches_the_geodetic_chain_within_a_micrometre(
        heading: float) -> None:
    # show -> ENU -> geodetic -> NED at the EKF origin, as pymap3d computes it point by
    # point, against the one matrix per EKF origin the control loop applies.
    import pymap3d

    origin = GeoOrigin(ORIGIN.lat, ORIGIN.lon, ORIGIN.alt, heading)
    ekfs = [geo_offset(ORIGIN, 120.0, -80.0, 3.0), geo_offset(ORIGIN, -900.0, 400.0, -12.0)]
    for ekf in ekfs:
        lat, lon, alt = show_to_geodetic(origin, POINTS)
        n, e, d = pymap3d.geodetic2ned(lat, lon, alt, ekf.lat_deg, ekf.lon_deg, ekf.alt_m)
        chain = np.stack([n, e, d], axis=-1)
        np.testing.assert_allclose(show_to_ned(origin, ekf, POINTS), chain, atol=1e-6)
        lat, lon, alt = pymap3d.ned2geodetic(chain[:, 0], chain[:, 1], chain[:, 2],
                                             ekf.lat_deg, ekf.lon_deg, ekf.alt_m)
        np.testing.assert_allclose(ned_to_show(origin, ekf, chain),
                                   geodetic_to_show(origin, lat, lon, alt), atol=1e-6)
    per_row = [ekfs[i % 2] for i in range(len(POINTS))]
    ned = show_to_ned(origin, per_row, POINTS)
    np.testing.assert_allclose(ned[1], show_to_ned(origin, ekfs[1], POINTS[1]), atol=1e-9)
    np.testing.assert_allclose(ned_to_show(origin, per_row, ned), POINTS, atol=1e-6)


def test_vehicles_with_different_origins_get_targets_offset_by_the_origin_gap() -> None:
    # Vehicle B's EKF origin is 30 m north-east-ish of vehicle A's: the same show
    # point must be 30 m "closer" in B's frame, exactly the origin offset.
    a = geo_offset(ORIGIN, 0.0, 0.0)
    b = geo_offset(ORIGIN, 18.0, 24.0)  # 30 m away
    point = np.array([[5.0, 7.0, 10.0]])
    ned_a = show_to_ned(ORIGIN, [a], point)[0]
    ned_b = show_to_ned(ORIGIN, [b], point)[0]
    np.testing.assert_allclose(ned_a - ned_b, [24.0, 18.0, 0.0], atol=1e-3)
    np.testing.assert_allclose(ned_a, [7.0, 5.0, -10.0], atol=1e-3)


def test_per_vehicle_origins_convert_the_fleet_in_one_call() -> None:
    origins = [geo_offset(ORIGIN, 0.0, 0.0), geo_offset(ORIGIN, -30.0, 0.0)]
    ned = show_to_ned(ORIGIN, origins, np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 5.0]]))
    np.testing.assert_allclose(ned, [[0.0, 0.0, -5.0], [0.0, 30.0, -5.0]], atol=1e-3)


def test_heading_90_points_show_y_east_and_x_south() -> None:
    east_facing = GeoOrigin(ORIGIN.lat, ORIGIN.lon, ORIGIN.alt, 90.0)
    np.testing.assert_allclose(show_to_enu(east_facing, [0.0, 1.0, 0.0]), [1.0, 0.0, 0.0],
                               atol=1e-12)
    np.testing.assert_allclose(show_to_enu(east_facing, [1.0, 0.0, 0.0]), [0.0, -1.0, 0.0],
                               atol=1e-12)
    ned = show_to_ned(east_facing, geo_offset(ORIGIN, 0.0, 0.0), [10.0, 20.0, 5.0])
    np.testing.assert_allclose(ned, [-10.0, 20.0, -5.0], atol=1e-3)
    np.testing.assert_allclose(show_vel_to_ned(east_facing, [1.0, 2.0, 3.0]),
                               [-1.0, 2.0, -3.0], atol=1e-12)


def test_velocity_rotation_round_trips() -> None:
    origin = GeoOrigin(ORIGIN.lat, ORIGIN.lon, ORIGIN.alt, 33.0)
    vel = np.array([[1.0, -2.0, 0.5], [0.0, 3.0, -1.0]])
    np.testing.assert_allclose(ned_vel_to_show(origin, show_vel_to_ned(origin, vel)), vel,
                               atol=1e-12)


def test_bad_shapes_name_the_argument() -> None:
    with pytest.raises(ValueError, match="`xyz` must have shape"):
        show_to_ned(ORIGIN, geo_offset(ORIGIN, 0.0, 0.0), [1.0, 2.0])
    with pytest.raises(ValueError, match="`ekf_origin` has 2 origins"):
        show_to_ned(ORIGIN, [geo_offset(ORIGIN, 0, 0)] * 2, np.zeros((3, 3)))


def test_fleet_telemetry_to_show_positions() -> None:
    a = make_vehicle(1, ned=(2.0, 1.0, -0.5))
    b = make_vehicle(2, ned=(-24.0, -18.0, 0.0), ekf_origin=geo_offset(ORIGIN, 18.0, 24.0))
    c = make_vehicle(3)
    c.ekf_origin = None
    pos = show_positions(ORIGIN, {1: a, 2: b, 3: c})
    assert pos[1] is not None and pos[2] is not None and pos[3] is None
    np.testing.assert_allclose(pos[1], np.array([1.0, 2.0, 0.5]), atol=1e-3)
    np.testing.assert_allclose(pos[2], np.zeros(3), atol=1e-3)
