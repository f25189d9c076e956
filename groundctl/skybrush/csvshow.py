"""Skybrush Studio's CSV export: a folder (or a zip) of one CSV file per drone.

Each file has a row per frame: time in milliseconds, x, y, z in metres, and
the colour as red, green, blue bytes (0..255); Studio writes a header line
(``Time [msec],x [m],y [m],z [m],Red,Green,Blue``), which is skipped when the
first row is not numbers.  Drones are taken in the natural order of the file
names (``Drone 2`` before ``Drone 10``).

The samples become each drone's cubic Hermite curve through every few of them
(knots at least :data:`KNOT_SPACING` apart, so that the millimetre rounding of
the rows does not become acceleration), with velocities from central
differences (one-sided at the ends): that curve is what groundctl flies and
verifies.  Colours are linear between rows, exact at every row.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from groundctl.errors import ImportedShowError
from groundctl.files import FileProblem, MiB, read_regular_file
from groundctl.show.ranges import MAX_COORD, MAX_DRONE_STEPS, MAX_DRONES
from groundctl.skybrush.archive import ArchiveProblem, open_zip
from groundctl.skybrush.lights import LightKey
from groundctl.skybrush.model import BezierTrack, SkyDrone, SkyShow, hermite_to_bezier
from groundctl.skybrush.reader import MAX_SHOW_SECONDS

#: Largest CSV file of one drone (a 10-minute show at 24 fps is about 0.6 MiB).
MAX_CSV_BYTES = 16 * MiB
#: Largest sum of the CSV files (the rows groundctl may plan, MAX_DRONE_STEPS, are
#: about 60 MiB of CSV).
MAX_CSV_TOTAL = 64 * MiB
#: Knots of a CSV drone's curve are at least this far apart (every few rows), s.
KNOT_SPACING = 0.2


def _natural(name: str) -> list[object]:
    return [int(p) if p.isdigit() else p.lower() for p in re.split(r"(\d+)", name)]


def read_csv_show(path: str | Path) -> SkyShow:
    """The show in the CSV folder or zip at ``path``; ImportedShowError on any problem."""
    p = Path(path)
    files: list[tuple[str, bytes]] = []
    try:
        if p.is_dir():
            names = sorted((c for c in p.iterdir() if c.suffix.lower() == ".csv"),
                           key=lambda c: _natural(c.name))
            if len(names) > MAX_DRONES:
                raise ImportedShowError(path, f"{len(names)} CSV files, more than the "
                                              f"{MAX_DRONES} drones groundctl flies")
            for c in names:
                files.append((c.name, read_regular_file(c, MAX_CSV_BYTES)))
                _total(path, files)
        else:
            with open_zip(p) as zf:
                members = sorted((m for m in zf.members if m.lower().endswith(".csv")
                                  and not m.rsplit("/", 1)[-1].startswith(".")),
                                 key=_natural)
                if len(members) > MAX_DRONES:
                    raise ImportedShowError(path, f"{len(members)} CSV files, more than the "
                                                  f"{MAX_DRONES} drones groundctl flies")
                for m in members:
                    files.append((m.rsplit("/", 1)[-1], zf.read(m, MAX_CSV_BYTES)))
                    _total(path, files)
    except FileProblem as exc:
        raise ImportedShowError(path, f"CSV show: {exc}") from None
    except ArchiveProblem as exc:
        raise ImportedShowError(path, f"not a CSV show archive: {exc}") from None
    if not files:
        raise ImportedShowError(path, "no .csv files: a Skybrush Studio CSV export has one "
                                      "per drone")
    budget = MAX_DRONE_STEPS
    drones = []
    for name, data in files:
        try:
            drone = _drone(name, data)
        except ValueError as exc:
            raise ImportedShowError(path, f"{name}: {exc}") from None
        budget -= len(drone.track.times)
        if budget < 0:
            raise ImportedShowError(path, f"more than {MAX_DRONE_STEPS} samples in all")
        drones.append(drone)
    return SkyShow(title=p.stem[:100] or "csv", drones=tuple(drones))


def _total(path: str | Path, files: list[tuple[str, bytes]]) -> None:
    if sum(len(d) for _, d in files) > MAX_CSV_TOTAL:
        raise ImportedShowError(path, f"the CSV files hold more than {MAX_CSV_TOTAL // MiB} "
                                      "MiB")


def _drone(name: str, data: bytes) -> SkyDrone:
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError("not UTF-8 text") from None
    rows: list[list[float]] = []
    for n, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        cells = [c.strip() for c in line.split(",")]
        try:
            values = [float(c) for c in cells]
        except ValueError:
            if not rows and n == 1:
                continue  # the header
            raise ValueError(f"line {n}: not numbers") from None
        if len(values) != 7:
            raise ValueError(f"line {n}: {len(values)} columns, not 7 (time ms, x, y, z, "
                             "red, green, blue)")
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"line {n}: a value is not finite")
        rows.append(values)
        if len(rows) > MAX_DRONE_STEPS:
            raise ValueError(f"more than {MAX_DRONE_STEPS} rows")
    if len(rows) < 2:
        raise ValueError("fewer than two samples")
    a = np.array(rows)
    t = a[:, 0] / 1000.0
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise ValueError(f"sample {k + 2}: time does not increase")
    if t[0] < 0 or t[-1] > MAX_SHOW_SECONDS:
        raise ValueError(f"times must lie within 0..{MAX_SHOW_SECONDS:g} s")
    pos = a[:, 1:4]
    if np.abs(pos).max() > MAX_COORD:
        raise ValueError(f"a position lies more than {MAX_COORD:g} m from the origin")
    rgb = a[:, 4:7]
    if rgb.min() < 0 or rgb.max() > 255 or np.any(rgb != np.round(rgb)):
        raise ValueError("colours must be whole numbers 0..255")
    # Knots at least KNOT_SPACING apart: the rows are rounded to the millimetre, and a
    # curve through every row of a 24 fps export would turn that rounding into up to
    # 6 x 0.5 mm / (1/24 s)^2 = 1.7 m/s^2 of acceleration that nobody planned.
    stride = max(1, math.ceil(KNOT_SPACING / float(np.median(np.diff(t))) - 1e-9))
    idx = np.arange(0, len(t), stride)
    if idx[-1] != len(t) - 1:
        idx = np.append(idx, len(t) - 1)
    tk, pk = t[idx], pos[idx]
    vel = np.gradient(pk, tk, axis=0, edge_order=1)
    h = np.diff(tk)
    ctrl = hermite_to_bezier(pk[:-1], vel[:-1], pk[1:], vel[1:], h)
    keys = tuple(LightKey(float(ti), (int(c[0]), int(c[1]), int(c[2])))
                 for ti, c in zip(t, rgb, strict=True))
    return SkyDrone(name=Path(name).stem, home=pos[0].copy(), track=BezierTrack(tk, ctrl),
                    lights=keys)


#: The header Skybrush Studio writes.
HEADER = "Time [msec],x [m],y [m],z [m],Red,Green,Blue"


def write_csv_show(show: SkyShow, folder: str | Path, fps: float = 10.0) -> Path:
    """``show`` as a CSV export in ``folder``: one file per drone, a row per frame at
    ``fps`` (times in whole milliseconds, positions to the millimetre, colour bytes)."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    end = max(d.track.end for d in show.drones)
    frames = int(np.floor(end * fps + 1e-9)) + 1
    t = np.round(np.arange(frames) / fps, 3)
    if t[-1] < end - 1e-9:
        t = np.append(t, round(end, 3))
    for d in show.drones:
        pos, _ = d.track.evaluate(t)
        kt = np.array([k.t for k in d.lights]) if d.lights else np.array([0.0])
        kc = np.array([k.rgb for k in d.lights], dtype=float) if d.lights else np.zeros((1, 3))
        rgb = np.column_stack([np.interp(t, kt, kc[:, c]) for c in range(3)])
        lines = [HEADER]
        for ti, p, c in zip(t, pos, np.round(rgb).astype(int), strict=True):
            lines.append(f"{round(ti * 1000)},{p[0]:.3f},{p[1]:.3f},{p[2]:.3f},"
                         f"{c[0]},{c[1]},{c[2]}")
        (out / f"{d.name}.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return out
