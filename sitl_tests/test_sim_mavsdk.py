"""An independent MAVLink implementation (MAVSDK, C++ via ctypes) flies a PX4-flavoured vehicle.

If MAVSDK disagrees with the simulator, the simulator is wrong until proven
otherwise: this test connects, arms, takes off, flies an offboard position
setpoint and reads telemetry, all through MAVSDK's own PX4 logic.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest
from ports import reserved_udp_port

from groundctl.clock import ScaledClock
from groundctl.link.flavours import Flavour
from groundctl.sim import SimConfig, SimFleet

mavsdk = pytest.importorskip("mavsdk")
from mavsdk import ComponentType, Configuration, Mavsdk  # noqa: E402
from mavsdk.plugins.action import Action, ActionError  # noqa: E402
from mavsdk.plugins.offboard import Offboard, PositionNedYaw  # noqa: E402
from mavsdk.plugins.telemetry import FlightMode, Telemetry  # noqa: E402

SPEED = 2.0



def _until(pred: Callable[[], bool], timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return
        time.sleep(0.05)
    raise AssertionError(f"MAVSDK: {what} not seen within {timeout} s")


@pytest.mark.slow
def test_mavsdk_arms_takes_off_and_flies_offboard_on_px4_flavour() -> None:
    port = reserved_udp_port()
    cfg = SimConfig(count=1, flavour=Flavour.PX4, gcs=("127.0.0.1", port),
                    ekf_origin_delay_s=0.5, ready_delay_s=1.0)
    fleet = SimFleet(cfg, ScaledClock(SPEED))
    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        sdk.add_any_connection(f"udpin://127.0.0.1:{port}")
        fleet.start()
        system = sdk.first_autopilot(10.0)
        assert system is not None, "MAVSDK did not discover the simulated autopilot"
        telemetry, action, offboard = Telemetry(system), Action(system), Offboard(system)

        _until(lambda: fleet.time > 1.2, 5, "vehicle ready")
        for _ in range(20):
            try:
                action.arm()
                break
            except ActionError:
                time.sleep(0.2)
        _until(telemetry.armed, 5, "armed")
        assert fleet.state(1).armed

        action.takeoff()
        _until(lambda: telemetry.flight_mode() == FlightMode.TAKEOFF, 5, "TAKEOFF mode")
        _until(telemetry.in_air, 10, "in air")
        _until(lambda: telemetry.position().relative_altitude_m > 2.3, 15, "takeoff altitude")
        _until(lambda: telemetry.flight_mode() == FlightMode.HOLD, 10, "HOLD after takeoff")

        offboard.set_position_ned(PositionNedYaw(5.0, 2.0, -4.0, 0.0))
        time.sleep(0.3)
        offboard.start()
        _until(lambda: telemetry.flight_mode() == FlightMode.OFFBOARD, 5, "OFFBOARD mode")

        def there() -> bool:
            p = telemetry.position_velocity_ned().position
            return abs(p.north_m - 5.0) < 0.3 and abs(p.east_m - 2.0) < 0.3 and \
                abs(p.down_m + 4.0) < 0.3
        _until(there, 20, "offboard position setpoint reached")
        truth = fleet.state(1).position  # ENU, EKF origin = home = show origin
        assert abs(truth[0] - 2.0) < 0.4 and abs(truth[1] - 5.0) < 0.4 and abs(truth[2] - 4) < 0.4
        pos = telemetry.position()
        assert abs(pos.latitude_deg - cfg.origin[0]) < 1e-4
        assert abs(pos.relative_altitude_m - 4.0) < 0.4
        assert telemetry.battery().remaining_percent > 50

        action.land()
        _until(lambda: not telemetry.armed(), 30, "disarmed after landing")
        assert fleet.state(1).landed
    finally:
        sdk.destroy()
        fleet.stop()
