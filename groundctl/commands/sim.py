"""``groundctl sim``: run a simulated fleet until Ctrl-C, one status line per second.

With ``--show SHOW`` the fleet stands on that show's takeoff slots, one
vehicle per slot, so that ``groundctl fly SHOW`` against it passes the
pre-flight slot check.  The slots come from where ``fly`` gets them: a plan's
``home`` is the show's ``[takeoff]`` layout copied unchanged by the planner
(and saved as is in a ``.npz`` plan), in the show frame of its ``[origin]``
(heading included), so the show file is read but never planned.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from groundctl.commands.options import (
    add_fail,
    add_gust_on,
    add_points_dir,
    push,
    signing_key,
    weak,
)
from groundctl.errors import EXIT_OK, SimulatorError
from groundctl.execute.frames import show_to_enu
from groundctl.link.flavours import Flavour
from groundctl.show.model import GeoOrigin, Limits
from groundctl.sim.config import PROFILE_NAMES, SimConfig, grid_layout, profile_for, wind_from
from groundctl.sim.faults import LinkFaults
from groundctl.vehicleid import VehicleId, network_layout, networks_for

if TYPE_CHECKING:
    from groundctl.sim.fleet import SimFleet

#: Grid spacing of the homes when neither ``--layout`` nor ``--show`` places them, m.
DEFAULT_SPACING = 3.0


@dataclass(frozen=True)
class TakeoffSlots:
    """Where a show's fleet stands before takeoff: what ``groundctl fly`` assigns vehicles to."""

    name: str
    """The show's name."""
    source: Path
    """The show file (TOML) or plan file (``.npz``) they were read from."""
    origin: GeoOrigin
    """The show frame's geodetic anchor and heading."""
    home: NDArray[np.float64]
    """(drones, 3) takeoff slots, show-frame metres (``Plan.home``)."""
    land_battery_pct: float = 20.0
    """The show's ``[limits] land_battery_pct`` (what ``--fail ...:battery`` drains to
    three quarters of)."""
    pads: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    """(spares, 3) the spares' pads, show frame, m: a plan's, or a show file's given
    ones (laid-out pads are the planner's: plan the show to stand spares on them)."""

    @property
    def drones(self) -> int:
        """One vehicle per slot."""
        return len(self.home)

    @property
    def vehicles(self) -> int:
        """One per slot and one per spare pad."""
        return len(self.home) + len(self.pads)

    def homes_enu(self) -> NDArray[np.float64]:
        """The slots, then the spare pads, as ENU metres from :attr:`origin`, as
        :class:`SimConfig` takes homes."""
        return show_to_enu(self.origin, np.concatenate([self.home, self.pads]))


def takeoff_slots(path: Path, points_dirs: Sequence[Path] = ()) -> TakeoffSlots:
    """The takeoff slots ``groundctl fly PATH`` checks vehicles against, without planning.

    A ``.npz`` plan file gives its saved ``home`` (PlanFileError if it is not
    one); anything else is read and validated as a show file (ShowFileError),
    whose ``home`` the planner copies to the plan unchanged.
    """
    if path.suffix == ".npz":  # the same rule as `fly` (commands.flying.load_or_plan)
        from groundctl.plan.plan import Plan
        plan = Plan.load(path)
        pads = plan.spares.pads if plan.spares is not None else np.zeros((0, 3))
        return TakeoffSlots(plan.show_name, path, plan.origin,
                            np.asarray(plan.home, dtype=float), plan.limits.land_battery_pct,
                            np.asarray(pads, dtype=float))
    from groundctl.show.loader import load_show
    show = load_show(path, points_dirs)
    given = np.zeros((0, 3))
    if show.spares is not None:
        xy = show.spares.pads if show.spares.pads is not None else (
            show.spares.points[:, :2] if show.spares.points is not None else None)
        if xy is not None:
            given = np.column_stack([np.asarray(xy, dtype=float)[:, :2], np.zeros(len(xy))])
    return TakeoffSlots(show.name, path, show.origin, np.asarray(show.home, dtype=float),
                        show.limits.land_battery_pct, given)


def _floats(text: str, n: int, what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what} must be {n} comma-separated numbers, "
                                         f"not {text!r}") from None
    if len(values) != n:
        raise argparse.ArgumentTypeError(f"{what} must be {n} comma-separated numbers, "
                                         f"not {text!r}")
    return values


def _origin(text: str) -> tuple[float, ...]:
    return _floats(text, 3, "--origin LAT,LON,ALT")


def _wind(text: str) -> tuple[float, ...]:
    return _floats(text, 3, "--wind EAST,NORTH,UP")


def _endpoint(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise argparse.ArgumentTypeError(f"--gcs must be HOST:PORT, not {text!r}")
    return host, int(port)


def _layout(text: str) -> float:
    kind, sep, spacing = text.partition(":")
    if kind != "grid" or not sep:
        raise argparse.ArgumentTypeError(f"--layout must be grid:SPACING, not {text!r}")
    try:
        value = float(spacing)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--layout spacing must be a number, not {spacing!r}")\
            from None
    if not value > 0:
        raise argparse.ArgumentTypeError("--layout spacing must be positive")
    return value


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:  # type: ignore[type-arg]
    """Register ``groundctl sim``."""
    p = subparsers.add_parser(
        "sim", help="simulate a fleet of MAVLink vehicles on UDP",
        description="Simulate N ArduCopter- or PX4-like vehicles, each on its own UDP socket, "
                    "sending to the ground station. Runs until Ctrl-C.")
    p.add_argument("--show", type=Path, default=None, metavar="SHOW",
                   help="stand on this show's takeoff slots (show file or .npz plan): its "
                        "origin, heading, layout and drone count, ready for 'groundctl fly "
                        "SHOW'")
    add_points_dir(p)
    p.add_argument("--count", type=int, default=None,
                   help="number of vehicles (default 1, or the show's drone count)")
    p.add_argument("--autopilot", choices=[f.value for f in Flavour], default="ardupilot",
                   help="autopilot flavour (default ardupilot)")
    p.add_argument("--gcs", type=_endpoint, action="append", default=None,
                   help="ground station HOST:PORT (default 127.0.0.1:14550); repeat it for "
                        "several MAVLink networks, one per --gcs in order (as many as "
                        "--networks)")
    p.add_argument("--networks", type=int, default=0, metavar="K",
                   help="spread the fleet over K MAVLink networks, system ids from 1 on "
                        "each (default: one per --gcs, or as many as the fleet needs at 254 "
                        "vehicles each); network n's vehicles send to the n-th --gcs")
    p.add_argument("--origin", type=_origin, default=None,
                   help="show origin LAT,LON,ALT (default ArduPilot SITL's home; not with "
                        "--show)")
    p.add_argument("--layout", type=_layout, default=None, metavar="grid:SPACING",
                   help="homes on a grid with this spacing in metres (default grid:3; not "
                        "with --show)")
    p.add_argument("--sysid-base", type=int, default=1, help="first system id (default 1)")
    p.add_argument("--bind", default="127.0.0.1", help="address vehicles bind to")
    p.add_argument("--base-port", type=int, default=0,
                   help="first vehicle UDP port, the others follow (default: ephemeral)")
    p.add_argument("--speed", type=float, default=1.0, help="simulated seconds per second")
    p.add_argument("--rate", type=float, default=50.0, help="physics rate, Hz (default 50)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random process")
    p.add_argument("--wind", type=_wind, default=(0.0, 0.0, 0.0),
                   help="mean wind EAST,NORTH,UP in m/s")
    p.add_argument("--gust", type=float, default=0.0, help="random gust std-dev, m/s")
    p.add_argument("--gps-noise", type=float, default=0.01, help="position-estimate noise, m")
    p.add_argument("--ekf-delay", type=float, default=20.0,
                   help="seconds until the EKF origin is set (SITL: 20)")
    p.add_argument("--ready-delay", type=float, default=40.0,
                   help="seconds until arming is allowed (SITL: 40)")
    p.add_argument("--loss", type=float, default=0.0, help="packet loss probability")
    p.add_argument("--latency", type=float, default=0.0, help="one-way latency, ms")
    p.add_argument("--jitter", type=float, default=0.0, help="latency std-dev, ms")
    p.add_argument("--duplicate", type=float, default=0.0, help="packet duplication probability")
    p.add_argument("--signing-key", type=signing_key, default=None,
                   help="MAVLink 2 signing key as 64 hex digits")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="autopilot parameter at boot (repeatable), e.g. FS_GCS_ENABLE=1")
    p.add_argument("--profile", choices=PROFILE_NAMES, default=None,
                   help="flight-dynamics calibration (default: ardupilot-4.8 or px4-1.15)")
    p.add_argument("--push", type=push, action="append", default=[], metavar="SYSID@T:E,N,U",
                   help="carry a vehicle E,N,U metres (east, north, up) over one second at T "
                        "simulated seconds after boot, whatever its autopilot does: "
                        "kinematic, a GPS jump or a bird strike (repeatable; a gust is "
                        "--gust-on)")
    add_gust_on(p, "T simulated seconds after boot")
    add_fail(p, "T simulated seconds after boot")
    p.add_argument("--weak", type=weak, action="append", default=[],
                   metavar="SYSID[,SYSID...]:FACTOR",
                   help="scale those vehicles' speed and acceleration authority by FACTOR")
    p.add_argument("--boot-text", action="store_true",
                   help="send the autopilot's boot text before MAVLink, as ArduPilot SITL does")
    p.set_defaults(func=run)
    return p


def _placement(args: argparse.Namespace, slots: TakeoffSlots | None
               ) -> tuple[int, dict[str, object]]:
    """The vehicle count and the SimConfig fields that place the homes."""
    if slots is None:
        count = 1 if args.count is None else args.count
        spacing = DEFAULT_SPACING if args.layout is None else args.layout
        place: dict[str, object] = {
            "positions": grid_layout(count, spacing) if count > 0 else None}
        if args.origin is not None:
            place["origin"] = args.origin
        return count, place
    shown = f"--show {slots.source}"
    if args.count is not None and args.count != slots.vehicles:
        spares = f" and {len(slots.pads)} spare pads" if len(slots.pads) else ""
        raise SimulatorError(f"--count {args.count} conflicts with {shown}: the show has "
                             f"{slots.drones} drones, one per takeoff slot{spares}; leave "
                             "--count out")
    if args.origin is not None:
        raise SimulatorError(f"--origin conflicts with {shown}: the fleet stands at the "
                             f"show's own origin; leave --origin out")
    if args.layout is not None:
        raise SimulatorError(f"--layout conflicts with {shown}: the fleet stands on the "
                             f"show's takeoff slots; leave --layout out")
    o = slots.origin
    return slots.vehicles, {"origin": (o.lat, o.lon, o.alt), "positions": slots.homes_enu()}


def build_config(args: argparse.Namespace, slots: TakeoffSlots | None = None) -> SimConfig:
    """The SimConfig the parsed arguments describe.

    ``slots`` are the takeoff slots of ``args.show``, read here if not given.
    """
    if slots is None and args.show is not None:
        slots = takeoff_slots(args.show, getattr(args, "points_dir", ()))
    count, place = _placement(args, slots)
    params: dict[str, float] = {}
    for item in args.param:
        name, sep, value = item.partition("=")
        try:
            params[name.strip().upper()] = float(value)
        except ValueError:
            raise SimulatorError(f"--param {item!r}: expected NAME=NUMBER") from None
        if not sep:
            raise SimulatorError(f"--param {item!r}: expected NAME=NUMBER")
    gcs: list[tuple[str, int]] = args.gcs or [("127.0.0.1", 14550)]
    try:
        networks = networks_for(count, args.networks or (len(gcs) if len(gcs) > 1 else 0))
    except ValueError as exc:
        raise SimulatorError(str(exc)) from None
    spread: dict[str, object] = {}
    if networks > 1:
        if len(gcs) != networks:
            raise SimulatorError(f"{networks} networks need {networks} --gcs addresses (one "
                                 f"ground-station port each), got {len(gcs)}")
        if args.sysid_base != 1:
            raise SimulatorError("--sysid-base is for one network: with several, each "
                                 "numbers its vehicles from 1")
        nets, ids = network_layout(count, networks)
        spread = {"networks": nets, "gcs_networks": gcs}
    else:
        if len(gcs) > 1:
            raise SimulatorError(f"{len(gcs)} --gcs addresses for one network")
        ids = [args.sysid_base + i for i in range(count)] if count > 0 else []
    try:
        return SimConfig(
            count=count, flavour=Flavour(args.autopilot), gcs=gcs[0],
            system_ids=ids or None, bind_host=args.bind, base_port=args.base_port,
            physics_rate_hz=args.rate, ekf_origin_delay_s=args.ekf_delay,
            ready_delay_s=args.ready_delay, wind=args.wind, gust_std=args.gust,
            gps_noise_m=args.gps_noise, seed=args.seed, signing_key=args.signing_key,
            link_faults=LinkFaults(args.loss, args.latency, args.jitter, args.duplicate),
            params=params, boot_text=args.boot_text,
            dynamics=profile_for(Flavour(args.autopilot), args.profile),
            **place, **spread)  # type: ignore[arg-type]
    except ValueError as exc:
        raise SimulatorError(str(exc)) from exc


def status_line(fleet: SimFleet) -> str:
    """One line: time, armed / flying counts, modes, packet counters."""
    states = fleet.snapshot()
    modes = Counter(s.mode for s in states)
    armed = sum(s.armed for s in states)
    flying = sum(not s.landed for s in states)
    bad = sum(s.bad_packets for s in states)
    rx = sum(s.packets_in for s in states)
    tx = sum(s.packets_out for s in states)
    mode_text = " ".join(f"{m}:{n}" for m, n in sorted(modes.items()))
    return (f"t={fleet.time:7.1f}s vehicles={len(states)} armed={armed} flying={flying} "
            f"modes[{mode_text}] rx={rx} tx={tx} bad={bad} overruns={fleet.overruns}")


def run(args: argparse.Namespace) -> int:
    """Run the fleet until Ctrl-C."""
    if args.speed <= 0:
        raise SimulatorError("--speed must be positive")
    slots = takeoff_slots(args.show, args.points_dir) if args.show is not None else None
    config = build_config(args, slots)
    from groundctl.clock import ScaledClock
    from groundctl.sim.faults import failed_battery
    from groundctl.sim.fleet import SimFleet

    fleet = SimFleet(config, ScaledClock(args.speed))
    ports = fleet.ports
    port_text = ",".join(map(str, ports)) if len(ports) <= 8 else \
        f"{ports[0]},{ports[1]},...,{ports[-1]}"
    where = "" if slots is None else \
        f" on the takeoff slots of show {slots.name!r} ({slots.source})"
    ids = [VehicleId(s) for s in config.sysids()]
    gcs = config.gcs_networks or [config.gcs]
    sending = ", ".join(f"{h}:{p}" for h, p in gcs)
    nets = f" over {len(gcs)} networks" if len(gcs) > 1 else ""
    print(f"groundctl sim: {config.count} {config.flavour.value} vehicles{where}{nets}, "
          f"sysid {ids[0]}..{ids[-1]}, sending to {sending}, ports {port_text}, "
          f"speed x{args.speed:g}", flush=True)
    # A service manager stops us with SIGTERM: the same clean stop as Ctrl-C.
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        for sysid, at, offset in args.push:
            fleet.push(offset, sysid, at=at)
        for sysid, at, speed, frm, duration in args.gust_on:
            fleet.gust(wind_from(speed, frm), duration, sysid, at=at)
        for sysid, factor in (w for group in args.weak for w in group):
            fleet.weaken(factor, sysid)
        for sysid, at, kind in args.fail:
            if kind == "motor":
                fleet.motor_failure(sysid, at=at)
            elif kind == "battery":
                # The show's landing level with --show, else the default (20 %).
                level = slots.land_battery_pct if slots is not None \
                    else Limits().land_battery_pct
                fleet.low_battery(failed_battery(level), sysid, at=at)
            else:
                fleet.cut_link(sysid, at=at)
        fleet.start()
        while True:
            time.sleep(1.0)
            print(status_line(fleet), flush=True)
    except KeyboardInterrupt:
        print("groundctl sim: stopping", file=sys.stderr)
    finally:
        fleet.stop()
        signal.signal(signal.SIGTERM, previous)
    return EXIT_OK


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt
