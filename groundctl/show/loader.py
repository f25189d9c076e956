"""Read a show file (TOML) into a validated :class:`Show`.

Every problem is a :class:`ShowFileError` that names the file, the place
(``[limits]``, ``formation 3 'star'``) and the key, the rule and the value,
and a way out where there is one.  Beyond types and ranges the loader checks
what would otherwise only fail in the planner or in the air: slots closer
than the separation, slots outside the geofence or the altitude band, and
transitions shorter than the limits allow (after assigning drones to slots
the same way the planner will).

The schema (every key; all tables but [show], [origin] and [[formation]]
optional)::

    [show]      name, drones, takeoff_altitude = 3
    [origin]    lat, lon, alt, heading = 0
    [limits]    max_speed_h, max_speed_up, max_speed_down, max_accel,
                min_separation, min_altitude, max_altitude, geofence = [[x, y], ...],
                land_battery_pct = 20, max_flight_time = 900,
                max_wind = 10
    [model]     kind = "quadrotor" | "unicycle"; unicycle: speed, r_min, max_turn_rate
    [planner]   dt, steps, max_iterations, tolerance, pattern_tolerance, alpha, beta,
                tracking_margin, budget
    [takeoff]   layout = "grid" | "points" | "random", layout keys, headings
    [[formation]] shape, transition, name, center, plane, rotation, hold,
                color | gradient (+ gradient_axis) | colors, shape keys
    [landing]   transition, hold = 0, color = "#000000"
    [mpc]       enabled = true, horizon = 3, trigger_error = 0.4, release_error = 0.15,
                release_after = 2
    [vehicle]   fence = false, fence_action = "land", fence_margin = 2, gcs_failsafe,
                gcs_timeout, offboard_loss, rtl_alt, land_speed, set = true,
                params = { NAME = value, ardupilot = {...}, px4 = {...} }

Every number has a range (:mod:`groundctl.show.ranges`, docs/show-files.md's "Ranges"),
checked before a shape is generated or a matrix allocated; point files must be
regular files of bounded size under the show file's directory (or a directory
the operator allows with ``--points-dir``).
"""

from __future__ import annotations

import hashlib
import math
import re
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from groundctl.errors import ShowFileError
from groundctl.files import FileProblem, read_regular_file
from groundctl.plan.assign import assign_chain
from groundctl.plan.feasibility import airborne_time, min_transition_time
from groundctl.plan.qp_build import MAX_TOLERANCE
from groundctl.show import checks
from groundctl.show.colors import ColorError, parse_color
from groundctl.show.formations import Context, formation_where, read_formation
from groundctl.show.model import (
    Formation,
    GeoOrigin,
    Limits,
    Model,
    MpcSettings,
    PlannerSettings,
    QuadrotorModel,
    Show,
    SpareSettings,
    SpareStandby,
    UnicycleModel,
    VehicleSettings,
)
from groundctl.show.ranges import (
    DT,
    LIMIT_RANGES,
    MAX_ASSIGN_CELLS,
    MAX_DRONE_STEPS,
    MAX_DRONES,
    MAX_FORMATIONS,
    MAX_GEOFENCE_CORNERS,
    MAX_NAME_CHARS,
    MAX_RAW_PARAMS,
    MAX_SHOW_FILE_BYTES,
    MAX_SPARES,
    MAX_STEPS,
    MPC_RANGES,
    ORIGIN_RANGES,
    PARAM_VALUE,
    TAKEOFF_ALTITUDE,
    VEHICLE_RANGES,
    Range,
    above_zero,
)
from groundctl.show.reader import MISSING, Table, closest, describe, fmt
from groundctl.show.takeoff import read_headings, read_home

TOP_LEVEL = ("show", "origin", "limits", "model", "planner", "takeoff", "formation", "landing",
             "mpc", "vehicle", "spares")
SPARE_STANDBY = ("ground", "air")
FENCE_ACTIONS = ("land", "rtl", "brake", "report")
GCS_FAILSAFES = ("off", "land", "rtl", "brake")
OFFBOARD_LOSS = ("land", "rtl", "hold")
_VEHICLE_KEYS = ("fence", "fence_action", "fence_margin", "gcs_failsafe", "gcs_timeout",
                 "offboard_loss", "rtl_alt", "land_speed", "set", "params")
#: A parameter id: at most 16 characters (MAVLink's param_id), upper case, digits, _.
_PARAM_NAME = re.compile(r"[A-Z][A-Z0-9_]{0,15}")
MODEL_KINDS = ("quadrotor", "unicycle")
_UNICYCLE_KEYS = ("speed", "r_min", "max_turn_rate")
#: Show-file key -> Limits field.
_LIMIT_KEYS = {
    "max_speed_h": "max_speed_h",
    "max_speed_up": "max_speed_up",
    "max_speed_down": "max_speed_down",
    "max_accel": "max_accel",
    "min_separation": "min_separation",
    "min_altitude": "min_alt",
    "max_altitude": "max_alt",
    "land_battery_pct": "land_battery_pct",
    "max_flight_time": "max_flight_time",
    "max_wind": "max_wind",
}
#: Most parts of a dotted key or table name (``a.b.c`` has 3); show files use 2.
MAX_KEY_PARTS = 32
# One key part (bare, or quoted), possessive so that no input makes the search backtrack,
# and a run started only at the beginning of a word, so that each is scanned once.  It
# looks at the text, not at TOML: 33 dot-separated words inside a string count too.
_KEY_PART = r"""(?:[A-Za-z0-9_-]++|"[^"\n]*+"|'[^'\n]*+')"""
_DEEP_KEY = re.compile(rf"""(?<![A-Za-z0-9_"'.-]){_KEY_PART}"""
                       rf"(?:[ \t]*+\.[ \t]*+{_KEY_PART}){{{MAX_KEY_PARTS}}}")
LANDING_SHAPE = "home"
LANDING_COLOR = "#000000"


def load_show(path: str | Path, points_dirs: Sequence[str | Path] = ()) -> Show:
    """Read and validate the show file at ``path``; :class:`ShowFileError` on any problem.

    ``points_dirs`` are directories, besides the show file's own, that point
    files (``file = "..."``) may be read from.
    """
    p = Path(path)
    try:
        raw = read_regular_file(p, MAX_SHOW_FILE_BYTES)
    except FileProblem as exc:
        raise ShowFileError(p, "", str(exc)) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ShowFileError(p, "", f"not UTF-8 text (byte {exc.start})") from None
    deep = _DEEP_KEY.search(text)
    if deep:
        # tomllib's work and memory grow with the square of a dotted key's length: a
        # 200 KB key of 100,000 parts takes minutes and tens of gigabytes.
        line = text.count("\n", 0, deep.start()) + 1
        raise ShowFileError(p, f"line {line}", f"a dotted key or table name has more than "
                                               f"{MAX_KEY_PARTS} parts")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise _syntax_error(p, exc) from None
    except RecursionError:  # tomllib recurses once per nested array or inline table
        raise ShowFileError(p, "", "TOML syntax error: arrays or inline tables nested too "
                                   "deeply") from None
    return parse_show(data, str(p), p.parent, points_dirs=points_dirs, source=raw)


def load_vehicle_settings(path: str | Path) -> VehicleSettings | None:
    """The ``[vehicle]`` table of the show file at ``path`` (None: it has none), read
    without planning anything (the flying commands, once the show was loaded)."""
    p = Path(path)
    try:
        raw = read_regular_file(p, MAX_SHOW_FILE_BYTES)
        data = tomllib.loads(raw.decode("utf-8"))
    except FileProblem as exc:
        raise ShowFileError(p, "", str(exc)) from None
    except (UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError):
        return load_show(p).vehicle  # its own precise message
    return read_vehicle_settings(data, str(p))


def _table_file(path: str | Path, table: str, why: str) -> tuple[Path, Table]:
    """The ``[table]`` of any TOML file given for one table alone (a show file, or one
    with only that table); ShowFileError in one line, ``why`` saying what it is for."""
    p = Path(path)
    try:
        data = tomllib.loads(read_regular_file(p, MAX_SHOW_FILE_BYTES).decode("utf-8"))
    except FileProblem as exc:
        raise ShowFileError(p, "", str(exc)) from None
    except UnicodeDecodeError:
        raise ShowFileError(p, "", f"not UTF-8 text (a [{table}] table is TOML)") from None
    except tomllib.TOMLDecodeError as exc:
        raise _syntax_error(p, exc) from None
    except RecursionError:
        raise ShowFileError(p, "", "TOML syntax error: arrays or inline tables nested too "
                                   "deeply") from None
    if table not in data:
        raise ShowFileError(p, "", f"no [{table}] table ({why})")
    return p, _table(data, table, str(p))


def load_vehicle_file(path: str | Path) -> VehicleSettings:
    """The ``[vehicle]`` table of any TOML file (``--vehicle FILE``: a show file, or one
    with only that table); its fence is the flown plan's geofence."""
    _, t = _table_file(path, "vehicle", "--vehicle takes the vehicles' own settings from one")
    return _read_vehicle(t, None)


def load_limits_file(path: str | Path) -> dict[str, Any]:
    """The keys the ``[limits]`` table of any TOML file gives (``--limits FILE`` for a
    Skybrush show: a show file, or one with only that table), as :class:`Limits` fields
    and values; each checked as a show file's are."""
    _, t = _table_file(path, "limits", "--limits takes the envelope your vehicles fly "
                                       "from one")
    limits = _read_limits(t)
    given = {field: getattr(limits, field) for key, field in _LIMIT_KEYS.items() if t.has(key)}
    if t.has("geofence"):
        given["geofence"] = limits.geofence
    return given


def _syntax_error(path: Path, exc: tomllib.TOMLDecodeError) -> ShowFileError:
    # tomllib puts the position in the message: "Invalid value (at line 3, column 9)".
    text = str(exc)
    m = re.search(r"\s*\(at line (\d+), column (\d+)\)$", text)
    if m is None:
        return ShowFileError(path, "", f"TOML syntax error: {text}")
    return ShowFileError(path, f"line {m[1]}, column {m[2]}",
                         f"TOML syntax error: {text[:m.start()]}")


def _table(data: dict[str, Any], key: str, path: str, required: bool = False) -> Table:
    where = f"[{key}]"
    value = data.get(key)
    if value is None:
        if required:
            raise ShowFileError(path, "", f"missing required table [{key}]")
        value = {}
    if not isinstance(value, dict):
        raise ShowFileError(path, where, f"must be a table, got {describe(value)}")
    return Table(value, path, where)


def _check_top_level(data: dict[str, Any], path: str) -> None:
    for key in data:
        if key not in TOP_LEVEL:
            near = closest(key, TOP_LEVEL)
            near_s = f"[[{near}]]" if near == "formation" else f"[{near}]"
            hint = f"; did you mean {near_s}?" if near else f"; valid: {', '.join(TOP_LEVEL)}"
            raise ShowFileError(path, "", f"unknown table or key '{key}'{hint}")


def _read_limits(t: Table) -> Limits:
    t.check_keys((*_LIMIT_KEYS, "geofence"))
    d = Limits()
    values = {field: t.ranged(key, getattr(d, field), LIMIT_RANGES[field])
              for key, field in _LIMIT_KEYS.items() if field != "land_battery_pct"}
    battery = t.number("land_battery_pct", d.land_battery_pct, positive=True)
    if battery >= 100.0:
        raise t.error(f"'land_battery_pct' {fmt(battery)} must be below "
                      "100 (the percentage below which a drone leaves the show to land)")
    values["land_battery_pct"] = battery
    if values["max_alt"] <= values["min_alt"]:
        raise t.error(f"'max_altitude' {fmt(values['max_alt'])} m must be above "
                      f"'min_altitude' {fmt(values['min_alt'])} m")
    fence = None
    if t.has("geofence"):
        pts = t.point_list("geofence", (2,), min_count=3, max_count=MAX_GEOFENCE_CORNERS)
        area = 0.5 * np.abs(np.dot(pts[:, 0], np.roll(pts[:, 1], 1))
                            - np.dot(pts[:, 1], np.roll(pts[:, 0], 1)))
        if area <= 1e-9:
            raise t.error("'geofence' encloses no area; give at least 3 corners [x, y] in order")
        fence = tuple((float(x), float(y)) for x, y in pts)
    return Limits(**values, geofence=fence)


def _read_model(t: Table) -> Model:
    kind = t.string("kind", "quadrotor", choices=MODEL_KINDS)
    if kind == "quadrotor":
        t.check_keys(("kind",), {k: "a key of kind \"unicycle\"" for k in _UNICYCLE_KEYS})
        return QuadrotorModel()
    t.check_keys(("kind", *_UNICYCLE_KEYS))
    d = UnicycleModel()
    return UnicycleModel(speed=t.ranged("speed", d.speed, above_zero(50.0)),
                         r_min=t.ranged("r_min", d.r_min, above_zero(10_000.0)),
                         max_turn_rate=t.ranged("max_turn_rate", d.max_turn_rate,
                                                above_zero(100.0)))


def _read_planner(t: Table) -> PlannerSettings:
    t.check_keys(("dt", "steps", "max_iterations", "tolerance", "pattern_tolerance",
                  "alpha", "beta", "tracking_margin", "budget"))
    d = PlannerSettings()
    weight = Range(0.0, 1e6)
    return PlannerSettings(
        dt=t.ranged("dt", d.dt, DT),
        # Larger tolerances would let the SCP stop while a pair it left out drifts close.
        tolerance=t.number("tolerance", d.tolerance, positive=True, maximum=MAX_TOLERANCE),
        pattern_tolerance=t.ranged("pattern_tolerance", d.pattern_tolerance,
                                   above_zero(10.0)),
        steps=t.integer("steps", 0, minimum=2, maximum=MAX_STEPS) if t.has("steps")
        else d.steps,
        max_iterations=t.integer("max_iterations", d.max_iterations, minimum=1,
                                 maximum=1000),
        alpha=t.ranged("alpha", d.alpha, weight),
        beta=t.ranged("beta", d.beta, weight),
        tracking_margin=t.number("tracking_margin", d.tracking_margin, minimum=0.0,
                                 maximum=1.0),
        budget_s=t.number("budget", d.budget_s, minimum=1.0, maximum=3600.0),
    )


def _read_mpc(t: Table) -> MpcSettings:
    t.check_keys(("enabled", "horizon", "trigger_error", "release_error", "release_after"))
    d = MpcSettings()
    enabled = t.get("enabled", d.enabled)
    if not isinstance(enabled, bool):
        raise t.error(f"'enabled' must be true or false, got {describe(enabled)}")
    trigger = t.ranged("trigger_error", d.trigger_error_m, MPC_RANGES["trigger_error_m"])
    release = t.ranged("release_error", min(d.release_error_m, trigger / 2),
                       MPC_RANGES["release_error_m"])
    if release >= trigger:
        raise t.error(f"'release_error' {fmt(release)} m must be below 'trigger_error' "
                      f"{fmt(trigger)} m")
    return MpcSettings(enabled=enabled,
                       horizon_s=t.number("horizon", d.horizon_s, minimum=0.5, maximum=10.0),
                       trigger_error_m=trigger, release_error_m=release,
                       release_after_s=t.ranged("release_after", d.release_after_s,
                                                MPC_RANGES["release_after_s"]))


def _flag(t: Table, key: str, default: bool) -> bool:
    value = t.get(key, default)
    if not isinstance(value, bool):
        raise t.error(f"'{key}' must be true or false, got {describe(value)}")
    return value


def _raw_params(t: Table, key: str, value: object) -> tuple[tuple[str, float], ...]:
    if not isinstance(value, dict):
        raise t.error(f"'{key}' must be a table of NAME = number, got {describe(value)}")
    if len(value) > MAX_RAW_PARAMS:
        raise t.error(f"'{key}' must have at most {MAX_RAW_PARAMS} parameters, got "
                      f"{len(value)}")
    out = []
    for name, x in value.items():
        if not _PARAM_NAME.fullmatch(name):
            raise t.error(f"'{key}' parameter name {describe(name)} must be 1-16 characters "
                          "A-Z, 0-9 or _, starting with a letter (e.g. FENCE_ACTION)")
        problem = PARAM_VALUE.problem(f"{key}.{name}", x)
        if problem:
            raise t.error(problem)
        out.append((name, float(x)))
    return tuple(out)


def _read_vehicle(t: Table, limits: Limits | None) -> VehicleSettings:
    """``limits`` None: the table comes without its show (``--vehicle FILE``), and the
    fence is checked against the flown plan's geofence before arming."""
    t.check_keys(_VEHICLE_KEYS)
    d = VehicleSettings()
    fence = _flag(t, "fence", d.fence)
    if fence and limits is not None and limits.geofence is None:
        raise t.error("'fence' = true needs a [limits] geofence to upload; add "
                      "geofence = [[x, y], ...] or set fence = false")

    def optional(key: str) -> float | None:
        return t.ranged(key, MISSING, VEHICLE_RANGES[key]) if t.has(key) else None

    def choice(key: str, choices: tuple[str, ...]) -> Any:
        return t.string(key, MISSING, choices=choices) if t.has(key) else None

    raw = t.get("params", {})
    if not isinstance(raw, dict):
        raise t.error(f"'params' must be a table of NAME = number, got {describe(raw)}")
    flat = {k: v for k, v in raw.items() if k not in ("ardupilot", "px4")}
    return VehicleSettings(
        fence=fence,
        fence_action=t.string("fence_action", d.fence_action,  # type: ignore[arg-type]
                              choices=FENCE_ACTIONS),
        fence_margin=t.ranged("fence_margin", d.fence_margin, VEHICLE_RANGES["fence_margin"]),
        gcs_failsafe=choice("gcs_failsafe", GCS_FAILSAFES),
        gcs_timeout=optional("gcs_timeout"),
        offboard_loss=choice("offboard_loss", OFFBOARD_LOSS),
        rtl_alt=optional("rtl_alt"),
        land_speed=optional("land_speed"),
        set=_flag(t, "set", d.set),
        params=_raw_params(t, "params", flat),
        params_ardupilot=_raw_params(t, "params.ardupilot", raw.get("ardupilot", {})),
        params_px4=_raw_params(t, "params.px4", raw.get("px4", {})),
    )


def read_vehicle_settings(data: dict[str, Any], path: str) -> VehicleSettings | None:
    """Only the ``[vehicle]`` table of a parsed show file (None: the show has none)."""
    if "vehicle" not in data:
        return None
    return _read_vehicle(_table(data, "vehicle", path), _read_limits(_table(data, "limits",
                                                                            path)))


def _landing(t: Table, home: np.ndarray, takeoff_altitude: float, index: int,
             unicycle: bool, max_flight_time: float) -> Formation:
    t.check_keys(("transition", "hold", "color"))
    transition = t.number("transition", positive=True, maximum=max_flight_time)
    hold = t.number("hold", 0.0, minimum=0.0, maximum=max_flight_time)
    if unicycle and hold > 0:
        raise t.error(f"'hold' must be 0 for the unicycle model, got {fmt(hold)}: "
                      "it flies at constant speed and cannot hover")
    try:
        color = parse_color(t.get("color", LANDING_COLOR))
    except ColorError as exc:
        raise t.error(f"'color': {exc}") from None
    points = home + np.array([0.0, 0.0, takeoff_altitude])
    return Formation(name="landing", shape=LANDING_SHAPE, points=points,
                     colors=np.tile(color, (len(points), 1)), transition_s=transition,
                     hold_s=hold, index=index)


def parse_show(data: dict[str, Any], path: str, base_dir: str | Path = ".", *,
               points_dirs: Sequence[str | Path] = (), source: bytes | None = None) -> Show:
    """Validate an already-parsed show file (``tomllib`` output) into a :class:`Show`.

    ``path`` is only used in messages; ``base_dir`` resolves relative file
    names (CSV point files), which must lie under it or under one of
    ``points_dirs``.  ``source`` is the show file's bytes: with it the show
    gets its :attr:`Show.digest`.
    """
    _check_top_level(data, path)
    st = _table(data, "show", path, required=True)
    st.check_keys(("name", "drones", "takeoff_altitude"))
    name = st.string("name", Path(path).stem or "show", max_length=MAX_NAME_CHARS)
    drones = st.integer("drones", minimum=1, maximum=MAX_DRONES)
    takeoff_altitude = st.ranged("takeoff_altitude", 3.0, TAKEOFF_ALTITUDE)

    ot = _table(data, "origin", path, required=True)
    ot.check_keys(("lat", "lon", "alt", "heading"))
    origin = GeoOrigin(lat=ot.ranged("lat", MISSING, ORIGIN_RANGES["lat"]),
                       lon=ot.ranged("lon", MISSING, ORIGIN_RANGES["lon"]),
                       alt=ot.ranged("alt", MISSING, ORIGIN_RANGES["alt"]),
                       heading_deg=ot.ranged("heading", 0.0, ORIGIN_RANGES["heading_deg"]))

    limits = _read_limits(_table(data, "limits", path))
    model = _read_model(_table(data, "model", path))
    planner = _read_planner(_table(data, "planner", path))
    unicycle = isinstance(model, UnicycleModel)

    if takeoff_altitude < limits.min_alt - 1e-9 or takeoff_altitude > limits.max_alt + 1e-9:
        raise st.error(f"'takeoff_altitude' {fmt(takeoff_altitude)} m is outside [limits] "
                       f"min_altitude {fmt(limits.min_alt)} m .. max_altitude "
                       f"{fmt(limits.max_alt)} m")

    tt = _table(data, "takeoff", path)
    layout = read_home(tt, drones, limits.min_separation, unicycle)
    home, seed = layout.home, layout.seed
    problem = (checks.separation_problem(home, limits.min_separation, layout.scale_key,
                                         layout.scale)
               or checks.coordinate_problem(home, "home")
               or checks.geofence_problem(home, limits, "home"))
    if problem:
        raise tt.error(problem.replace("points ", "homes ", 1))

    raw_formations = data.get("formation")
    if raw_formations is None:
        raise ShowFileError(path, "", "no formations; add at least one [[formation]] table")
    if not isinstance(raw_formations, list) or not all(isinstance(f, dict)
                                                       for f in raw_formations):
        raise ShowFileError(path, "[formation]", "must be an array of tables: write "
                            "[[formation]] (double brackets) before each formation")
    if len(raw_formations) > MAX_FORMATIONS:
        raise ShowFileError(path, "[formation]", f"at most {MAX_FORMATIONS} formations, got "
                                                 f"{len(raw_formations)}")

    ctx = Context(path=path, base_dir=Path(base_dir), drones=drones, model=model,
                  takeoff_altitude=takeoff_altitude, points_dirs=tuple(map(Path, points_dirs)),
                  max_flight_time=limits.max_flight_time)
    formations: list[Formation] = []
    for i, raw in enumerate(raw_formations, start=1):
        formation, table, local = read_formation(raw, i, ctx)
        problem = (_steps_problem(formation.transition_s, planner)
                   or checks.separation_problem(formation.points, limits.min_separation,
                                                local.scale_key, local.scale)
                   or checks.coordinate_problem(formation.points)
                   or checks.geofence_problem(formation.points, limits)
                   or checks.altitude_problem(formation.points, limits))
        if problem:
            raise table.error(problem)
        formations.append(formation)

    if tt.has("headings") and not unicycle:
        raise tt.error("'headings' only applies to [model] kind = \"unicycle\"")
    headings = read_headings(tt, drones, seed, home, formations[0].points.mean(axis=0))

    if "landing" in data:
        lt = _table(data, "landing", path)
        landing = _landing(lt, home, takeoff_altitude, len(formations) + 1, unicycle,
                           limits.max_flight_time)
        problem = _steps_problem(landing.transition_s, planner)
        if problem:
            raise lt.error(problem)
        formations.append(landing)

    mpc = _read_mpc(_table(data, "mpc", path))
    vehicle = _read_vehicle(_table(data, "vehicle", path), limits) if "vehicle" in data \
        else None
    spares = _read_spares(_table(data, "spares", path), limits, unicycle) \
        if "spares" in data else None
    digest = "" if source is None else _digest(source, ctx.files_read)
    show = Show(name=name, drones=drones, origin=origin, limits=limits, model=model, home=home,
                takeoff_altitude=takeoff_altitude, formations=tuple(formations),
                planner=planner, start_headings=headings, mpc=mpc, vehicle=vehicle,
                spares=spares, source=path, digest=digest)
    _check_budget(show, path)
    _check_transitions(show, path)
    return show


def _read_spares(t: Table, limits: Limits, unicycle: bool) -> SpareSettings:
    """``[spares]``: how many, where they wait, and the pads or points if given.  Only
    what the table says on its own is checked here; that they keep clear of the show's
    drones is the planner's to verify, once their paths exist."""
    t.check_keys(("count", "standby", "pads", "points", "altitude"))
    if unicycle:
        raise t.error("spares need a vehicle that can hover: [model] kind = \"quadrotor\"")
    count = t.integer("count", minimum=1, maximum=MAX_SPARES)
    standby: SpareStandby = "air" if t.string("standby", "ground",
                                              choices=SPARE_STANDBY) == "air" else "ground"
    pads = points = None
    altitude = None
    if standby == "ground":
        for key in ("points", "altitude"):
            if t.has(key):
                raise t.error(f"'{key}' is for spares waiting in the air (standby = \"air\"); "
                              "on the ground give 'pads' = [[x, y], ...]")
        if t.has("pads"):
            pads = t.point_list("pads", (2,), min_count=count, max_count=count)
    else:
        if t.has("pads"):
            raise t.error("'pads' is for spares waiting on the ground; in the air give "
                          "'points' = [[x, y, z], ...] (each spare's pad is straight below)")
        if t.has("points"):
            if t.has("altitude"):
                raise t.error("give either 'points' or 'altitude', not both (the points "
                              "say their own height)")
            points = t.point_list("points", (3,), min_count=count, max_count=count)
            z = points[:, 2]
            low = np.flatnonzero((z < limits.min_alt - 1e-9) | (z > limits.max_alt + 1e-9))
            if len(low):
                raise t.error(f"'points' point {int(low[0]) + 1} is at z = "
                              f"{fmt(float(z[low[0]]))} m, outside min_altitude "
                              f"{fmt(limits.min_alt)} .. max_altitude {fmt(limits.max_alt)} m")
        elif t.has("altitude"):
            altitude = t.number("altitude", minimum=limits.min_alt, maximum=limits.max_alt)
    given = points if points is not None else pads
    if given is not None:
        problem = (checks.separation_problem(given[:, :2], limits.min_separation, None, 1.0)
                   or checks.geofence_problem(np.column_stack([given[:, :2],
                                                               np.zeros(len(given))]),
                                              limits, "spare"))
        if problem:
            key = "points" if points is not None else "pads"
            raise t.error(f"'{key}': {problem.replace('points ', key + ' ', 1)}")
    return SpareSettings(count=count, standby=standby, pads=pads, points=points,
                         altitude=altitude)


def _digest(source: bytes, files: Sequence[tuple[str, bytes]]) -> str:
    """SHA-256 of the show file's bytes and of every point file it read, in order."""
    h = hashlib.sha256(b"groundctl show v1\0")
    for part in (source, *(b for pair in files for b in (pair[0].encode(), pair[1]))):
        h.update(len(part).to_bytes(8, "little"))
        h.update(part)
    return h.hexdigest()


def _steps_problem(transition_s: float, planner: PlannerSettings) -> str | None:
    """Message if a transition needs more QP steps than :data:`MAX_STEPS`."""
    steps = planner.steps_for(transition_s)
    if steps <= MAX_STEPS:
        return None
    need = math.ceil(transition_s / MAX_STEPS * 100 - 1e-9) / 100
    return (f"'transition' {fmt(transition_s)} s at [planner] dt {fmt(planner.dt)} s is "
            f"{steps} QP steps, more than {MAX_STEPS}; raise 'dt' to at least {need:g} s "
            f"or shorten the transition")


def _check_budget(show: Show, path: str) -> None:
    """The battery's endurance and the planner's work, before any of it is done."""
    planned = sum(f.transition_s + f.hold_s for f in show.formations)
    airborne = airborne_time(planned, show.takeoff_altitude, show.limits)
    limit = show.limits.max_flight_time
    if airborne > limit + 1e-9:
        raise ShowFileError(path, "[limits]", (
            f"the show keeps drones airborne {fmt(airborne)} s (climb, every transition and "
            f"hold, descent) but 'max_flight_time' is {fmt(limit)} s; shorten the show, or "
            f"raise 'max_flight_time' if the batteries last longer"))
    for f in show.formations:
        slots = len(f.points)
        if slots > show.drones and show.drones * slots > MAX_ASSIGN_CELLS:
            raise ShowFileError(path, f"formation {f.index} '{f.name}'", (
                f"{show.drones} drones x {slots} slots is {show.drones * slots} "
                f"assignment costs, more than {MAX_ASSIGN_CELLS} (a formation with "
                f"spare slots is assigned exactly); give it exactly {show.drones} slots"))
    steps = sum(show.planner.steps_for(f.transition_s) for f in show.formations)
    if show.drones * steps > MAX_DRONE_STEPS:
        raise ShowFileError(path, "[planner]", (
            f"{show.drones} drones x {steps} QP steps is {show.drones * steps} drone-steps, "
            f"more than {MAX_DRONE_STEPS}; raise 'dt', shorten the transitions or fly fewer "
            f"drones"))


def assigned_goals(show: Show) -> list[np.ndarray]:
    """Each formation's goal per drone, (drones, 3), assigned the way the planner does.

    The first transition starts at ``show.start_positions``; each later one
    at the previous formation's assigned goals.
    """
    points = [f.points for f in show.formations]
    chain = assign_chain(show.start_positions, points)
    return [pts[idx] for pts, idx in zip(points, chain, strict=True)]


def _check_transitions(show: Show, path: str) -> None:
    prev = show.start_positions
    for f, goal in zip(show.formations, assigned_goals(show), strict=True):
        bound = min_transition_time(prev, goal, show.limits, show.model)
        problem = checks.transition_problem(bound, f.transition_s, show.model)
        if problem:
            where = "[landing]" if f.shape == LANDING_SHAPE else formation_where(f.index, f.name)
            raise ShowFileError(path, where, problem)
        prev = goal
