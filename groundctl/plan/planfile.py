"""Reading a plan file that may come from anywhere: headers first, then every value checked.

A plan file is a zip of ``.npy`` members (NumPy's ``.npz``).  ``np.load``
would allocate whatever a member's header declares (a 16 MB file can declare
8.6 GB), describe random bytes as "pickled (object) data", and hand back NaN,
infinite or out-of-order values that the verifier then calls safe.  Here:

1. the file must be a regular file of at most :data:`MAX_PLAN_FILE_BYTES`;
2. every member's ``.npy`` header is read (``read_array_header_1_0`` /
   ``_2_0``) and the declared shapes are checked against each other and
   against the show-file ranges (:mod:`groundctl.show.ranges`) before a
   single array is allocated;
3. each array is then read to exactly its declared size, and must be finite;
   times strictly increasing, colours in [0, 1], the trajectories starting on
   their takeoff points;
4. the JSON metadata is read key by key with its types and ranges checked.

Every problem is one :class:`~groundctl.errors.PlanFileError`.
"""

from __future__ import annotations

import itertools
import json
import math
import re
import zipfile
import zlib
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import numpy.lib.format as npformat
from numpy.typing import NDArray

from groundctl.errors import PlanFileError
from groundctl.files import FileProblem, MiB, open_regular_file
from groundctl.show.model import GeoOrigin, Limits, MpcSettings
from groundctl.show.ranges import (
    LIMIT_RANGES,
    MAX_COORD,
    MAX_DRONE_STEPS,
    MAX_DRONES,
    MAX_FORMATIONS,
    MAX_GEOFENCE_CORNERS,
    MAX_NAME_CHARS,
    MAX_SPARES,
    MAX_STEPS,
    MPC_RANGES,
    ORIGIN_RANGES,
    TAKEOFF_ALTITUDE,
    Range,
)

FloatArray = NDArray[np.float64]

#: Bumped whenever the file layout changes incompatibly.
PLAN_FORMAT = 1
#: Largest plan file read at all (the largest allowed show's arrays are about 170 MB:
#: 10,000 drones' knots, colour keys and goals).
MAX_PLAN_FILE_BYTES = 256 * MiB
#: Most formation windows: every formation and the landing.
MAX_WINDOWS = MAX_FORMATIONS + 1
#: Most knots a plan of the largest allowed show has (every transition's steps, a knot
#: per hold, the start).
MAX_KNOTS = MAX_WINDOWS * (MAX_STEPS + 1) + 1
#: Most drone-knots (drones x knots) such a show has.
MAX_DRONE_KNOTS = MAX_DRONE_STEPS + MAX_DRONES * (MAX_WINDOWS + 1)
#: Most colour keyframes: the start, each arrival and each hold's end.
MAX_COLOR_KEYS = 2 * MAX_WINDOWS + 1
#: Most members a plan has: meta, six arrays, the spares' two, a goals array per window.
MAX_MEMBERS = 9 + MAX_WINDOWS
#: Largest zip central directory read: MAX_MEMBERS entries of ~100 bytes, with room.
MAX_DIRECTORY_BYTES = 64 * 1024
#: Longest metadata document, characters.
MAX_META_CHARS = 1 * MiB
#: Longest show a plan may hold: the longest battery endurance a show file may give, s.
MAX_DURATION = LIMIT_RANGES["max_flight_time"].high
#: How far a trajectory may start from its takeoff point raised to the takeoff altitude, m.
START_TOLERANCE = 0.01

_MEMBER = re.compile(r"(meta|times|pos|vel|home|color_times|colors|spare_pads|spare_points"
                     r"|goals_(?:0|[1-9]\d{0,2}))\.npy")
_ARRAYS = ("times", "pos", "vel", "home", "color_times", "colors")
_META_KEYS = {"format", "show_name", "origin", "limits", "mpc", "model", "takeoff_altitude",
              "formations", "show_digest", "names", "cues", "spares"}
#: Keys a plan may leave out (older plans, plans built from a TOML show).
_OPTIONAL_KEYS = {"mpc", "show_digest", "names", "cues", "spares"}
_SPARE_ARRAYS = ("spare_pads", "spare_points")
#: Most cues a plan holds.
MAX_CUES = 1000
_DIGEST = re.compile(r"[0-9a-f]{64}")


@dataclass(frozen=True)
class WindowRecord:
    """One formation window as the file gives it (before its goals are attached)."""

    index: int
    name: str
    start: float
    arrive: float
    end: float


@dataclass(frozen=True)
class PlanContents:
    """Everything a plan file holds, every value checked."""

    show_name: str
    origin: GeoOrigin
    limits: Limits
    mpc: MpcSettings
    model: str
    takeoff_altitude: float
    windows: tuple[WindowRecord, ...]
    show_digest: str
    names: tuple[str, ...]
    cues: tuple[tuple[float, str], ...]
    times: FloatArray
    pos: FloatArray
    vel: FloatArray
    home: FloatArray
    color_times: FloatArray
    colors: FloatArray
    goals: tuple[FloatArray, ...]
    spares: tuple[str, FloatArray, FloatArray, float, bool] | None = None
    """(standby, pads, points, clearance, given), as :class:`~groundctl.plan.plan.SparePlan`
    takes them."""


@dataclass(frozen=True)
class _Header:
    info: zipfile.ZipInfo
    shape: tuple[int, ...]
    dtype: np.dtype[Any]
    fortran: bool
    header_bytes: int

    @property
    def nbytes(self) -> int:
        return math.prod(self.shape) * self.dtype.itemsize


class _Bad(Exception):
    """A problem found while reading, before the path is attached."""


def read_plan_file(path: str | Path) -> PlanContents:
    """Read and check the plan file at ``path``; PlanFileError on any problem."""
    try:
        fh = open_regular_file(path, MAX_PLAN_FILE_BYTES)
    except FileProblem as exc:
        raise PlanFileError(path, str(exc) if exc.missing else
                            f"not a groundctl plan: {exc}") from None
    try:
        with fh:
            return _read(fh)
    except _Bad as exc:
        raise PlanFileError(path, f"not a groundctl plan: {exc}") from None


def _directory_bound(fh: BinaryIO) -> None:
    """Refuse a zip whose central directory is larger than a plan's, before ``ZipFile``
    reads all of it into memory: the entry count and size from the end record."""
    size = fh.seek(0, 2)
    tail_len = min(size, 22 + 0xFFFF)  # the end record and the longest comment
    fh.seek(size - tail_len)
    tail = fh.read(tail_len)
    at = tail.rfind(b"PK\x05\x06")
    if at < 0 or at + 22 > len(tail):
        raise _Bad("not a NumPy .npz archive (a zip of .npy arrays)")
    entries = int.from_bytes(tail[at + 10:at + 12], "little")
    directory = int.from_bytes(tail[at + 12:at + 16], "little")
    if entries > MAX_MEMBERS or directory > MAX_DIRECTORY_BYTES:
        raise _Bad(f"the archive lists {entries} members in {directory} bytes, more than a "
                   f"plan has")
    fh.seek(0)


def _read(fh: BinaryIO) -> PlanContents:
    _directory_bound(fh)
    try:
        zf = zipfile.ZipFile(fh)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError):
        raise _Bad("not a NumPy .npz archive (a zip of .npy arrays)") from None
    with zf:
        headers = _headers(zf)
        _shapes(headers)
        meta = _meta_document(zf, headers["meta"])
        arrays = {name: _array(zf, h, name) for name, h in headers.items() if name != "meta"}
    contents = _contents(meta, arrays)
    if len(contents.goals) != len(contents.windows):
        raise _Bad(f"{len(contents.goals)} goal arrays for {len(contents.windows)} formations")
    _check_consistency(contents)
    return contents


# -- headers ------------------------------------------------------------------------------


def _headers(zf: zipfile.ZipFile) -> dict[str, _Header]:
    infos = zf.infolist()
    if len(infos) > MAX_MEMBERS:
        raise _Bad(f"{len(infos)} members, more than a plan has")
    headers: dict[str, _Header] = {}
    for info in infos:
        m = _MEMBER.fullmatch(info.filename)
        if m is None:
            raise _Bad(f"unexpected member {info.filename[:80]!r}")
        name = m[1]
        if name in headers:
            raise _Bad(f"member '{name}' appears twice")
        if info.flag_bits & 0x1:
            raise _Bad(f"member '{name}' is encrypted")
        headers[name] = _header(zf, info, name)
    missing = [n for n in ("meta", *_ARRAYS) if n not in headers]
    if missing:
        raise _Bad(f"no {', '.join(repr(n) for n in missing)} array")
    goals = sorted(int(n[6:]) for n in headers if n.startswith("goals_"))
    if goals != list(range(len(goals))):
        raise _Bad("the goals_N arrays are not numbered 0, 1, 2, ...")
    return headers


def _header(zf: zipfile.ZipFile, info: zipfile.ZipInfo, name: str) -> _Header:
    try:
        with zf.open(info) as f:
            version = npformat.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = npformat.read_array_header_1_0(f)
            elif version == (2, 0):
                shape, fortran, dtype = npformat.read_array_header_2_0(f)
            else:
                raise _Bad(f"member '{name}' is .npy version {version[0]}.{version[1]}, "
                           "not 1.0 or 2.0")
            at = f.tell()
    except _Bad:
        raise
    except (zipfile.BadZipFile, zlib.error, OSError, NotImplementedError, RuntimeError):
        # a scrambled deflate stream, an unsupported compression, a bad CRC
        raise _Bad(f"member '{name}' is corrupt") from None
    except (ValueError, SyntaxError, TypeError, EOFError):
        # read_magic on random bytes, a header that is not a dict literal
        raise _Bad(f"member '{name}' is not a NumPy array") from None
    if dtype.hasobject:
        raise _Bad(f"member '{name}' holds Python objects (pickled data), which a plan "
                   "never does")
    if any(not isinstance(d, int) or d < 0 for d in shape):
        raise _Bad(f"member '{name}' declares the shape {shape!r}")
    return _Header(info, tuple(shape), dtype, bool(fortran), at)


def _shapes(h: Mapping[str, _Header]) -> tuple[int, int, int]:
    """Check every declared shape and type before reading: (drones, knots, colour keys)."""
    meta = h["meta"]
    if meta.dtype.kind != "U" or meta.shape != ():
        raise _Bad("'meta' is not a text document")
    if meta.dtype.itemsize > 4 * MAX_META_CHARS:
        raise _Bad(f"'meta' declares {meta.dtype.itemsize // 4} characters, more than "
                   f"{MAX_META_CHARS}")
    for name, hd in h.items():
        if name != "meta" and (hd.dtype.kind != "f" or hd.dtype.itemsize != 8):
            raise _Bad(f"'{name}' is {hd.dtype.name}, not 64-bit floats")
    times, pos = h["times"].shape, h["pos"].shape
    if len(times) != 1 or not 2 <= times[0] <= MAX_KNOTS:
        raise _Bad(f"'times' declares the shape {times}: a plan has 2 to {MAX_KNOTS} knots")
    knots = times[0]
    if len(pos) != 3 or pos[1:] != (knots, 3) or not 1 <= pos[0] <= MAX_DRONES:
        raise _Bad(f"'pos' declares the shape {pos}, not (drones, {knots}, 3) with 1 to "
                   f"{MAX_DRONES} drones")
    n = pos[0]
    if n * knots > MAX_DRONE_KNOTS:
        raise _Bad(f"{n} drones x {knots} knots is more than the {MAX_DRONE_KNOTS} a show "
                   "file may plan")
    keys_shape = h["color_times"].shape
    if len(keys_shape) != 1 or not 1 <= keys_shape[0] <= MAX_COLOR_KEYS:
        raise _Bad(f"'color_times' declares the shape {keys_shape}: 1 to {MAX_COLOR_KEYS} keys")
    keys = keys_shape[0]
    spares = [name for name in _SPARE_ARRAYS if name in h]
    if spares and len(spares) != len(_SPARE_ARRAYS):
        raise _Bad(f"'{spares[0]}' without its companion array")
    if spares:
        shape = h["spare_pads"].shape
        if len(shape) != 2 or shape[1] != 3 or not 1 <= shape[0] <= MAX_SPARES \
                or h["spare_points"].shape != shape:
            raise _Bad(f"'spare_pads' and 'spare_points' declare the shapes {shape} and "
                       f"{h['spare_points'].shape}, not both (spares, 3) with 1 to "
                       f"{MAX_SPARES} spares")
    want = {"vel": (n, knots, 3), "home": (n, 3), "colors": (n, keys, 3)}
    want.update({name: (n, 3) for name in h if name.startswith("goals_")})
    for name, shape in want.items():
        if h[name].shape != shape:
            raise _Bad(f"'{name}' declares the shape {h[name].shape}, not {shape}")
    return n, knots, keys


def _payload(zf: zipfile.ZipFile, h: _Header, name: str) -> bytes:
    """Exactly the member's declared data (the header already checked it is small enough)."""
    try:
        with zf.open(h.info) as f:
            f.read(h.header_bytes)
            data = f.read(h.nbytes)
            extra = f.read(1)
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, RuntimeError,
            NotImplementedError):
        raise _Bad(f"member '{name}' is corrupt") from None
    if len(data) != h.nbytes:
        raise _Bad(f"member '{name}' is cut short: {len(data)} of {h.nbytes} bytes")
    if extra:
        raise _Bad(f"member '{name}' has data after its array")
    return data


def _array(zf: zipfile.ZipFile, h: _Header, name: str) -> FloatArray:
    raw = np.frombuffer(_payload(zf, h, name), dtype=h.dtype)
    arr = raw.reshape(h.shape, order="F" if h.fortran else "C").astype(np.float64, copy=True)
    if not np.isfinite(arr).all():
        raise _Bad(f"'{name}' holds NaN or infinite values")
    return arr


def _meta_document(zf: zipfile.ZipFile, h: _Header) -> dict[str, Any]:
    raw = np.frombuffer(_payload(zf, h, "meta"), dtype=h.dtype)
    try:
        text = str(raw.reshape(()).item())
        doc = json.loads(text)
    except (ValueError, UnicodeError):
        raise _Bad("'meta' is not JSON") from None
    except RecursionError:
        raise _Bad("'meta' is JSON nested too deeply") from None
    if not isinstance(doc, dict):
        raise _Bad(f"'meta' is a JSON {type(doc).__name__}, not an object")
    return doc


# -- metadata -----------------------------------------------------------------------------


def _at(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


class _Doc:
    """One JSON object of the metadata, read key by key."""

    def __init__(self, data: object, where: str) -> None:
        if not isinstance(data, dict):
            raise _Bad(f"meta '{where}' must be an object, got {_kind(data)}")
        self.data: dict[str, Any] = data
        self.where = where

    def keys(self, allowed: Collection[str], required: Collection[str] = ()) -> None:
        unknown = sorted(set(self.data) - set(allowed))
        if unknown:
            raise _Bad(f"meta '{_at(self.where, str(unknown[0])[:40])}' is not a plan key")
        missing = sorted(set(required) - set(self.data))
        if missing:
            raise _Bad(f"meta '{_at(self.where, missing[0])}' is missing")

    def number(self, key: str, allowed: Range, default: float | None = None) -> float:
        if key not in self.data:
            if default is None:
                raise _Bad(f"meta '{_at(self.where, key)}' is missing")
            return default
        problem = allowed.problem(_at(self.where, key), self.data[key])
        if problem:
            raise _Bad(f"meta {problem}")
        return float(self.data[key])

    def integer(self, key: str, low: int, high: int) -> int:
        value = self.data.get(key)
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise _Bad(f"meta '{_at(self.where, key)}' must be an integer {low}..{high}, got "
                       f"{_kind(value)}")
        return value

    def name(self, key: str) -> str:
        value = self.data.get(key)
        if not isinstance(value, str) or len(value) > MAX_NAME_CHARS or not value.isprintable():
            raise _Bad(f"meta '{_at(self.where, key)}' must be printable text of at most "
                       f"{MAX_NAME_CHARS} characters, got {_kind(value)}")
        return value


def _kind(value: object) -> str:
    """A value for a message, bounded and printable whatever the file holds."""
    if value is None:
        return "null"
    if isinstance(value, bool | int | float):
        text = repr(value)
        return text if len(text) <= 40 else "a very large number"
    if isinstance(value, str):
        return repr(value) if len(value) <= 40 and value.isprintable() else "a string"
    return {"list": "a list", "dict": "an object"}.get(type(value).__name__, "a value")


def _limits(doc: _Doc) -> Limits:
    fields = set(LIMIT_RANGES) | {"geofence"}
    doc.keys(fields)
    d = Limits()
    values = {k: doc.number(k, r, getattr(d, k)) for k, r in LIMIT_RANGES.items()}
    if values["max_alt"] <= values["min_alt"]:
        raise _Bad("meta 'limits.max_alt' must be above 'limits.min_alt'")
    fence = doc.data.get("geofence")
    if fence is not None:
        ok = (isinstance(fence, list) and 3 <= len(fence) <= MAX_GEOFENCE_CORNERS
              and all(isinstance(p, list) and len(p) == 2
                      and all(Range(-MAX_COORD, MAX_COORD).problem("x", x) is None for x in p)
                      for p in fence))
        if not ok:
            raise _Bad(f"meta 'limits.geofence' must be 3 to {MAX_GEOFENCE_CORNERS} corners "
                       f"[x, y] within +-{MAX_COORD:g} m")
        fence = tuple((float(x), float(y)) for x, y in fence)
    return Limits(**values, geofence=fence)


def _mpc(doc: _Doc) -> MpcSettings:
    doc.keys({"enabled", *MPC_RANGES})
    d = MpcSettings()
    enabled = doc.data.get("enabled", d.enabled)
    if not isinstance(enabled, bool):
        raise _Bad(f"meta 'mpc.enabled' must be true or false, got {_kind(enabled)}")
    values = {k: doc.number(k, r, getattr(d, k)) for k, r in MPC_RANGES.items()}
    try:
        return MpcSettings(enabled=enabled, **values)
    except ValueError as exc:
        raise _Bad(f"meta 'mpc': {exc}") from None


def _windows(value: object) -> tuple[WindowRecord, ...]:
    if not isinstance(value, list) or not 1 <= len(value) <= MAX_WINDOWS:
        raise _Bad(f"meta 'formations' must be a list of 1 to {MAX_WINDOWS} formations, "
                   f"got {_kind(value) if not isinstance(value, list) else len(value)}")
    out = []
    span = Range(0.0, MAX_DURATION)
    for i, raw in enumerate(value):
        doc = _Doc(raw, f"formations.{i}")
        doc.keys({"index", "name", "start", "arrive", "end"},
                 {"index", "name", "start", "arrive", "end"})
        out.append(WindowRecord(doc.integer("index", 1, MAX_WINDOWS), doc.name("name"),
                                doc.number("start", span), doc.number("arrive", span),
                                doc.number("end", span)))
    return tuple(out)


def _names(value: object) -> tuple[str, ...]:
    """Each track's drone name (an imported show's), or none at all."""
    if not isinstance(value, list) or len(value) > MAX_DRONES:
        raise _Bad(f"meta 'names' must be a list of at most {MAX_DRONES} names, "
                   f"got {_kind(value)}")
    return tuple(_Doc({"name": v}, f"names.{i}").name("name") for i, v in enumerate(value))


def _cues(value: object) -> tuple[tuple[float, str], ...]:
    """The show's cues, (plan time, name), in time order."""
    if not isinstance(value, list) or len(value) > MAX_CUES:
        raise _Bad(f"meta 'cues' must be a list of at most {MAX_CUES} cues, got "
                   f"{_kind(value)}")
    out = []
    span = Range(-MAX_DURATION, MAX_DURATION)
    for i, raw in enumerate(value):
        doc = _Doc(raw, f"cues.{i}")
        doc.keys({"time", "name"}, {"time", "name"})
        out.append((doc.number("time", span), doc.name("name")))
    if any(b[0] < a[0] for a, b in itertools.pairwise(out)):
        raise _Bad("meta 'cues' are not in time order")
    return tuple(out)


def _contents(meta: dict[str, Any], arrays: dict[str, FloatArray]) -> PlanContents:
    doc = _Doc(meta, "")
    fmt = meta.get("format")
    if isinstance(fmt, bool) or fmt != PLAN_FORMAT:
        raise _Bad(f"plan format {_kind(fmt)} is not {PLAN_FORMAT}; re-plan the show")
    doc.keys(_META_KEYS, _META_KEYS - _OPTIONAL_KEYS)
    origin = _Doc(meta["origin"], "origin")
    origin.keys(set(ORIGIN_RANGES), {"lat", "lon", "alt"})
    model = meta["model"]
    if model not in ("quadrotor", "unicycle"):
        raise _Bad(f"meta 'model' must be \"quadrotor\" or \"unicycle\", got {_kind(model)}")
    digest = meta.get("show_digest", "")
    if not isinstance(digest, str) or (digest and not _DIGEST.fullmatch(digest)):
        raise _Bad(f"meta 'show_digest' must be 64 hex digits, got {_kind(digest)}")
    goals = tuple(arrays[f"goals_{i}"] for i in range(sum(k.startswith("goals_")
                                                          for k in arrays)))
    return PlanContents(
        show_name=doc.name("show_name"),
        origin=GeoOrigin(**{k: origin.number(k, r, 0.0 if k == "heading_deg" else None)
                            for k, r in ORIGIN_RANGES.items()}),
        limits=_limits(_Doc(meta["limits"], "limits")),
        mpc=_mpc(_Doc(meta["mpc"], "mpc")) if "mpc" in meta else MpcSettings(),
        model=model,
        takeoff_altitude=doc.number("takeoff_altitude", TAKEOFF_ALTITUDE),
        windows=_windows(meta["formations"]), show_digest=digest,
        names=_names(meta.get("names", [])), cues=_cues(meta.get("cues", [])),
        times=arrays["times"], pos=arrays["pos"], vel=arrays["vel"], home=arrays["home"],
        color_times=arrays["color_times"], colors=arrays["colors"], goals=goals,
        spares=_spares(meta.get("spares"), arrays))


def _spares(value: object, arrays: dict[str, FloatArray]
            ) -> tuple[str, FloatArray, FloatArray, float, bool] | None:
    """Where the spares wait: the meta's 'spares' and the two arrays, both or neither."""
    if value is None and "spare_pads" not in arrays:
        return None
    if value is None or "spare_pads" not in arrays:
        raise _Bad("meta 'spares' and the 'spare_pads' / 'spare_points' arrays come together")
    doc = _Doc(value, "spares")
    doc.keys({"standby", "given", "clearance_m"}, {"standby", "given", "clearance_m"})
    standby = doc.data["standby"]
    if standby not in ("ground", "air"):
        raise _Bad(f"meta 'spares.standby' must be \"ground\" or \"air\", got {_kind(standby)}")
    given = doc.data["given"]
    if not isinstance(given, bool):
        raise _Bad(f"meta 'spares.given' must be true or false, got {_kind(given)}")
    clearance = doc.number("clearance_m", Range(0.0, 2 * MAX_COORD))
    return standby, arrays["spare_pads"], arrays["spare_points"], clearance, given


# -- the plan as a whole ------------------------------------------------------------------


def _check_consistency(c: PlanContents) -> None:
    """What the verifier takes for granted: the timeline, the colours, where it starts."""
    times, keys = c.times, c.color_times
    if abs(times[0]) > 1e-9:
        raise _Bad(f"'times' starts at {times[0]:g} s, not at show time 0")
    if not np.all(np.diff(times) > 0):
        raise _Bad("'times' is not strictly increasing")
    if times[-1] > MAX_DURATION:
        raise _Bad(f"the plan lasts {times[-1]:g} s, longer than any battery a show file may "
                   f"give ({MAX_DURATION:g} s)")
    if not np.all(np.diff(keys) > 0):
        raise _Bad("'color_times' is not strictly increasing")
    if keys[0] < -1e-9 or keys[-1] > times[-1] + 1e-6:
        raise _Bad("'color_times' lies outside the plan's times")
    if c.colors.min() < 0.0 or c.colors.max() > 1.0:
        raise _Bad("'colors' must lie in [0, 1]")
    spare_arrays = () if c.spares is None else (("spare_pads", c.spares[1]),
                                                ("spare_points", c.spares[2]))
    for name, arr in (("home", c.home), ("pos", c.pos), *spare_arrays,
                      *((f"goals_{i}", g) for i, g in enumerate(c.goals))):
        if np.abs(arr).max() > MAX_COORD:
            raise _Bad(f"'{name}' lies more than {MAX_COORD:g} m from the origin")
    prev_end = 0.0
    for w in c.windows:
        if not (prev_end - 1e-6 <= w.start < w.arrive <= w.end <= times[-1] + 1e-6):
            raise _Bad(f"formation {w.index} '{w.name}' has start {w.start:g}, arrive "
                       f"{w.arrive:g}, end {w.end:g} s: not in order within the plan")
        prev_end = w.end
    if c.spares is not None:
        standby, pads, points = c.spares[:3]
        if not np.array_equal(points[:, :2], pads[:, :2]):
            raise _Bad("'spare_points' are not straight above their 'spare_pads'")
        if standby == "ground" and not np.array_equal(points, pads):
            raise _Bad("spares waiting on the ground wait on their pads, but 'spare_points' "
                       "differ from 'spare_pads'")
        if standby == "air" and not np.all(points[:, 2] > pads[:, 2]):
            raise _Bad("spares waiting in the air wait above their pads, but a "
                       "'spare_points' height is not above its pad's")
    if c.names and len(c.names) != len(c.pos):
        raise _Bad(f"meta 'names' names {len(c.names)} drones, the plan has {len(c.pos)}")
    start = c.home + np.array([0.0, 0.0, c.takeoff_altitude])
    off = np.linalg.norm(c.pos[:, 0] - start, axis=1)
    worst = int(np.argmax(off))
    if off[worst] > START_TOLERANCE:
        raise _Bad(f"track {worst} starts {off[worst]:.2f} m from its takeoff point raised to "
                   f"the takeoff altitude: its climb would not be the one planned")
