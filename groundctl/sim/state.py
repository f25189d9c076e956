"""Snapshots of the simulated vehicles, safe to hand to another thread."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class VehicleState:
    """One vehicle at one instant of simulated time."""

    sysid: int
    """MAVLink system id."""
    port: int
    """UDP port of the vehicle's socket on the bind host."""
    time: float
    """Simulated seconds since the fleet booted."""
    position: tuple[float, float, float]
    """True position, show-frame ENU metres."""
    velocity: tuple[float, float, float]
    """True velocity, ENU m/s."""
    estimated_position: tuple[float, float, float]
    """Position the autopilot believes (includes GPS error and glitches), ENU m."""
    armed: bool
    """Motors armed."""
    mode: str
    """Flight mode name (flavours.py names: GUIDED, LAND, OFFBOARD, AUTO.LOITER...)."""
    landed: bool
    """On the ground."""
    crashed: bool
    """Hit the ground too fast (after a motor failure, say)."""
    led: tuple[int, int, int]
    """Last LED colour set by LED_CONTROL (R, G, B)."""
    led_blink_hz: float
    """Blink rate from a 4-byte LED_CONTROL (0: steady)."""
    battery: float
    """Remaining battery fraction."""
    gcs_address: tuple[str, int]
    """Where the vehicle currently sends."""
    packets_in: int
    """Accepted MAVLink packets."""
    packets_out: int
    """Sent MAVLink packets (before link faults)."""
    bad_packets: int
    """Malformed, truncated or unknown packets ignored."""
    rejected_signature: int
    """Unsigned or badly signed packets rejected."""
    setpoints_dropped: int
    """Setpoints ignored because the vehicle was not in GUIDED / OFFBOARD."""
