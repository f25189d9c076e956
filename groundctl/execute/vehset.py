"""The vehicles' own safety settings (the show's ``[vehicle]`` table), enforced before arming.

:func:`targets_for` maps the operator's keys to each autopilot's parameters
and enum values (pure); :func:`fence_vertices` turns the show's geofence, grown
by ``fence_margin``, into the latitude/longitude polygon the vehicles get;
:func:`enforce` reads every parameter, sets those that differ (when ``set`` allows),
uploads the fence (under ``set = false`` downloads it instead and checks it is the
show's) and returns each vehicle's problems as one line each:
``FENCE_ACTION is 0, show needs 2 (land); not allowed to change it ([vehicle] set = false)``.

The mapping, from ArduCopter 4.x (``AC_Fence``, ``Copter::failsafe_gcs``) and
PX4 v1.15 (``geofence_params``, ``commander_params``, ``navigator_params``):

* ``fence = true``: ArduPilot FENCE_ENABLE 1, FENCE_TYPE 5 (altitude + polygon),
  FENCE_ALT_MAX = ceiling + margin, and the polygon; PX4 the polygon and
  GF_MAX_VER_DIST = ceiling + margin.
* ``fence_action``: ArduPilot FENCE_ACTION land 2, rtl 1, brake 4 (brake or land),
  report 0; PX4 GF_ACTION land 5, rtl 3, brake 2 (hold), report 1 (warning).
* ``gcs_failsafe``: ArduPilot FS_GCS_ENABLE off 0, rtl 1, land 5, brake 7 (brake or
  land); PX4 NAV_DLL_ACT off 0, brake 1 (hold), rtl 2, land 3.
* ``gcs_timeout``: ArduPilot FS_GCS_TIMEOUT (s); PX4 COM_DL_LOSS_T (whole s).
* ``offboard_loss``: PX4 COM_OBL_RC_ACT land 4, rtl 3, hold 5 (ArduPilot's GUIDED has
  no such action: GUID_TIMEOUT, which the runner sets).
* ``rtl_alt``: ArduPilot RTL_ALT_M (m, ArduCopter 4.8 and later) or RTL_ALT (cm, before);
  PX4 RTL_RETURN_ALT (m).
* ``land_speed``: ArduPilot LAND_SPD_MS (m/s, 4.8 and later) or LAND_SPEED (cm/s, before);
  PX4 MPC_LAND_SPEED (m/s).

The PX4 names are those of PX4-Autopilot's main branch too (its parameter definitions:
``commander_params.yaml``, ``geofence_params.yaml``, ``rtl_params.yaml``,
``multicopter_takeoff_land_params.yaml``): none renamed since v1.15.

A setting whose parameter a firmware version renamed (:attr:`ParamTarget.alternatives`,
:mod:`groundctl.link.paramnames`), raw ``params`` under either name included, is read
under every name at once, and the name the vehicle answers to is the one set,
in that name's unit; :attr:`VehicleOutcome.names` says which was used.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from groundctl.clock import Clock
from groundctl.execute.frames import show_to_geodetic
from groundctl.link.fence import (
    FenceDownload,
    FenceUpload,
    download_fence,
    inclusion_items,
    upload_fence,
)
from groundctl.link.flavours import Flavour
from groundctl.link.fleet import FleetLink
from groundctl.link.paramnames import ARDUCOPTER_OLD_NAMES, convert, si_name
from groundctl.link.params import ParamClient, run_params, same_value
from groundctl.link.window import per_network
from groundctl.show.model import GeoOrigin, Limits, VehicleSettings

#: FENCE_TYPE bits: 1 maximum altitude, 4 polygon.
ARDUPILOT_FENCE_TYPE = 1 | 4
_ARDU_FENCE_ACTION = {"land": 2, "rtl": 1, "brake": 4, "report": 0}
_PX4_GF_ACTION = {"land": 5, "rtl": 3, "brake": 2, "report": 1}
_ARDU_GCS = {"off": 0, "rtl": 1, "land": 5, "brake": 7}
_PX4_DLL = {"off": 0, "brake": 1, "rtl": 2, "land": 3}
_PX4_OBL = {"land": 4, "rtl": 3, "hold": 5}
#: A miter longer than this many margins is cut (a sharp corner would reach far out).
_MITER_LIMIT = 4.0


@dataclass(frozen=True)
class ParamTarget:
    """One parameter value the show needs."""

    name: str
    """The autopilot's parameter id."""
    value: float
    """The value needed, in the parameter's own unit."""
    why: str = ""
    """What it means, for messages ("land", "[vehicle] rtl_alt 20 m")."""
    alternatives: tuple[ParamTarget, ...] = ()
    """The same setting under the names other firmware versions give it, each with the
    value in its own unit (RTL_ALT_M 20 m; before ArduCopter 4.8, RTL_ALT 2000 cm)."""

    def needs(self) -> str:
        return f"{self.value:g}" + (f" ({self.why})" if self.why else "")

    @property
    def names(self) -> tuple[str, ...]:
        """Every name the setting may have, this one first."""
        return (self.name, *(a.name for a in self.alternatives))

    def under(self, name: str) -> ParamTarget:
        """The setting under the name ``name`` (one of :attr:`names`)."""
        return next(t for t in (self, *self.alternatives) if t.name == name)


def targets_for(settings: VehicleSettings, flavour: Flavour, limits: Limits) -> list[ParamTarget]:
    """The parameters ``settings`` asks of a vehicle of ``flavour``, in a fixed order."""
    s = settings
    out: list[ParamTarget] = []
    ceiling = limits.max_alt + s.fence_margin
    if flavour is Flavour.ARDUPILOT:
        if s.fence:
            out += [ParamTarget("FENCE_ENABLE", 1, "fence on"),
                    ParamTarget("FENCE_TYPE", ARDUPILOT_FENCE_TYPE, "altitude + polygon"),
                    ParamTarget("FENCE_ALT_MAX", ceiling, "ceiling + margin, m"),
                    ParamTarget("FENCE_ACTION", _ARDU_FENCE_ACTION[s.fence_action],
                                s.fence_action)]
        if s.gcs_failsafe is not None:
            out.append(ParamTarget("FS_GCS_ENABLE", _ARDU_GCS[s.gcs_failsafe], s.gcs_failsafe))
        if s.gcs_timeout is not None:
            out.append(ParamTarget("FS_GCS_TIMEOUT", s.gcs_timeout, "s"))
        # ArduCopter 4.8 renamed these to SI units; 4.5-4.7 still use centimetres.
        if s.rtl_alt is not None:
            out.append(_either("RTL_ALT_M", s.rtl_alt, "m", "cm"))
        if s.land_speed is not None:
            out.append(_either("LAND_SPD_MS", s.land_speed, "m/s", "cm/s"))
        raw = s.params_ardupilot
    else:
        if s.fence:
            out += [ParamTarget("GF_MAX_VER_DIST", ceiling, "ceiling + margin, m"),
                    ParamTarget("GF_ACTION", _PX4_GF_ACTION[s.fence_action], s.fence_action)]
        if s.gcs_failsafe is not None:
            out.append(ParamTarget("NAV_DLL_ACT", _PX4_DLL[s.gcs_failsafe], s.gcs_failsafe))
        if s.gcs_timeout is not None:
            out.append(ParamTarget("COM_DL_LOSS_T", math.ceil(s.gcs_timeout), "s"))
        if s.offboard_loss is not None:
            out.append(ParamTarget("COM_OBL_RC_ACT", _PX4_OBL[s.offboard_loss],
                                   s.offboard_loss))
        if s.rtl_alt is not None:
            out.append(ParamTarget("RTL_RETURN_ALT", s.rtl_alt, "m"))
        if s.land_speed is not None:
            out.append(ParamTarget("MPC_LAND_SPEED", s.land_speed, "m/s"))
        raw = s.params_px4
    names = {n for t in out for n in t.names}
    for name, value in (*s.params, *raw):
        # A raw ArduCopter parameter under either version's name is asked under both.
        renamed = si_name(name) if flavour is Flavour.ARDUPILOT else None
        if renamed is None:
            target = ParamTarget(name, value, "[vehicle] params")
        else:
            new = renamed[0]
            target = _either(new, convert(name, value, new), "[vehicle] params",
                             "[vehicle] params")
        if names & set(target.names):  # a raw parameter wins over the operator-level key
            out = [t for t in out if not set(t.names) & set(target.names)]
        out.append(target)
        names.update(target.names)
    return out


def _either(name: str, si: float, why: str, old_why: str) -> ParamTarget:
    """An ArduCopter setting under its 4.8 name ``name`` (``si`` in SI units), with the
    name it had before 4.8 as the alternative (in its own unit)."""
    old = ARDUCOPTER_OLD_NAMES[name][0]
    return ParamTarget(name, si, why,
                       (ParamTarget(old, round(convert(name, si, old), 6), old_why),))


def offset_polygon(xy: np.ndarray, margin: float) -> np.ndarray:
    """``xy`` (n, 2) grown outward by ``margin`` (each edge moved out, corners mitred, a
    miter longer than four margins cut to that)."""
    pts = np.asarray(xy, dtype=float)
    if margin == 0:
        return pts.copy()
    area2 = float(np.dot(pts[:, 0], np.roll(pts[:, 1], -1))
                  - np.dot(pts[:, 1], np.roll(pts[:, 0], -1)))
    sign = 1.0 if area2 > 0 else -1.0  # counter-clockwise: outward is to the right
    edge = np.roll(pts, -1, axis=0) - pts
    length = np.maximum(np.linalg.norm(edge, axis=1, keepdims=True), 1e-12)
    normal = sign * np.stack([edge[:, 1], -edge[:, 0]], axis=1) / length  # of edge i -> i+1
    prev = np.roll(normal, 1, axis=0)
    bis = prev + normal
    cos = np.clip(np.einsum("ij,ij->i", prev, normal), -0.999, 1.0)
    scale = margin / (1.0 + cos)  # |bis| * scale = margin / cos(half angle)
    offset = bis * scale[:, None]
    reach = np.linalg.norm(offset, axis=1, keepdims=True)
    offset = np.where(reach > _MITER_LIMIT * margin,
                      offset / np.maximum(reach, 1e-12) * _MITER_LIMIT * margin, offset)
    return pts + offset


def fence_vertices(origin: GeoOrigin, geofence: Sequence[tuple[float, float]],
                   margin: float) -> tuple[tuple[float, float], ...]:
    """The show's geofence (show-frame x, y), grown by ``margin``, as (lat, lon) degrees."""
    grown = offset_polygon(np.array(geofence, dtype=float), margin)
    xyz = np.column_stack([grown, np.zeros(len(grown))])
    lat, lon, _ = show_to_geodetic(origin, xyz)
    return tuple((float(a), float(b)) for a, b in zip(lat, lon, strict=True))


@dataclass
class VehicleOutcome:
    """What :func:`enforce` found and did on one vehicle."""

    problems: list[str]
    """Why the vehicle may not fly (empty: it may)."""
    changed: list[str]
    """Parameters set and confirmed, ``NAME a -> b``."""
    fence: bool = False
    """The fence was uploaded and accepted."""
    names: dict[str, str] = field(default_factory=dict)
    """For each setting a firmware version renamed: the name first asked for -> the name
    the vehicle answered to (``{"RTL_ALT_M": "RTL_ALT"}`` on ArduCopter 4.7)."""


async def _fence_matches(link: FleetLink, clock: Clock, sysid: int,
                         vertices: tuple[tuple[float, float], ...],
                         problems: list[str]) -> bool:
    """Under ``set = false`` the fence is not uploaded but checked: the vehicle's own (a
    download) must be the show's, item for item; what differs is one problem line."""
    download = FenceDownload(sysid)
    if not await download_fence(link, download, clock):
        problems.append(download.error or "fence download failed")
        return False
    held = tuple(download.items or ())
    if held == inclusion_items(vertices):
        return True
    have = f"its own fence has {len(held)} items" if held else "it has no fence"
    if held and len(held) == len(vertices):
        have += " at other places"
    problems.append(f"fence: {have}, show needs its {len(vertices)}-vertex inclusion "
                    "polygon; not allowed to change it ([vehicle] set = false)")
    return False


async def _one(link: FleetLink, clock: Clock, sysid: int, flavour: Flavour,
               settings: VehicleSettings, origin: GeoOrigin, limits: Limits,
               deadline_s: float) -> VehicleOutcome:
    out = VehicleOutcome([], [])
    if settings.fence and limits.geofence is None:
        out.problems.append("[vehicle] fence = true, but the plan has no geofence to fence "
                            "the vehicle in")
    elif settings.fence and limits.geofence is not None:
        vertices = fence_vertices(origin, limits.geofence, settings.fence_margin)
        if settings.set:
            upload = FenceUpload(sysid, vertices)
            # Bounded by itself: each message is sent at most `attempts` times.
            out.fence = await upload_fence(link, upload, clock)
            if not out.fence:
                out.problems.append(upload.error or "fence upload failed")
        else:
            out.fence = await _fence_matches(link, clock, sysid, vertices, out.problems)
    targets = targets_for(settings, flavour, limits)
    if not targets:
        return out
    # Five tries: a read is lost only when all five requests or answers are (0.6 % of
    # reads at 20 % loss each way, against 4.7 % with three).
    client = ParamClient(sysid, flavour, attempts=5)
    for t in targets:
        if t.alternatives:
            client.read_any(t.names)
        else:
            client.read(t.name)
    await run_params(link, client, clock, deadline_s)
    wanted: dict[str, ParamTarget] = {}
    for asked in targets:
        name = next((n for n in asked.names if n in client.values), None)
        if name is None:
            out.problems.append(client.failed.get(asked.name, f"{asked.name} not read") +
                                f" (show needs {asked.needs()})")
            continue
        if asked.alternatives:
            out.names[asked.name] = name
        t = asked.under(name)
        got = client.values[name]
        if same_value(got.value, t.value, got.type):
            continue
        if not settings.set:
            out.problems.append(f"{t.name} is {got.value:g}, show needs {t.needs()}; not "
                                "allowed to change it ([vehicle] set = false)")
            continue
        wanted[t.name] = t
        client.set(t.name, t.value, got.type)
    if wanted:
        before = {n: client.values[n].value for n in wanted}
        await run_params(link, client, clock, deadline_s)
        for name, t in wanted.items():
            if name in client.confirmed:
                out.changed.append(f"{name} {before[name]:g} -> {t.value:g}")
            else:
                out.problems.append(client.failed.get(name, f"{name} not confirmed"))
    return out


async def enforce(link: FleetLink, clock: Clock, flavours: Mapping[int, Flavour],
                  settings: VehicleSettings, origin: GeoOrigin, limits: Limits, *,
                  deadline_s: float = 20.0) -> dict[int, VehicleOutcome]:
    """Read, set (when allowed) and check every vehicle's parameters and upload the fence,
    :data:`~groundctl.link.window.PER_NETWORK` vehicles of each network at a time (each
    with its own window of requests); ``deadline_s`` of
    ``clock`` per parameter stage and vehicle (the fence upload is bounded by its own
    retries)."""
    ids = sorted(flavours)
    results = await per_network(ids, lambda s: _one(link, clock, s, flavours[s], settings,
                                                    origin, limits, deadline_s))
    return dict(zip(ids, results, strict=True))
