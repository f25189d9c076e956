"""The command-line side of Skybrush shows: options, and what ``plan``, ``check`` and
``dry-run`` do with a ``.skyc`` or a CSV export (the verbs keep one-line hooks)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from groundctl.errors import (
    EXIT_OK,
    EXIT_UNSAFE,
    ImportedShowError,
    UnsafePlan,
    WrongFileKind,
)
from groundctl.show.ranges import ORIGIN_RANGES, TAKEOFF_ALTITUDE
from groundctl.skybrush.model import orientation_of
from groundctl.skybrush.origin import DEFAULT_ORIGIN, OriginOption
from groundctl.skybrush.sniff import Kind, is_skybrush, sniff

if TYPE_CHECKING:
    from groundctl.plan.plan import Plan
    from groundctl.skybrush.importing import ImportResult

# The importer (and with it the planner and the verifier) is imported where a show is
# imported, not with the options: a command line that fails its parsing, or asks for
# --help, does not wait for scipy.


def origin(text: str) -> OriginOption:
    """``--origin LAT,LON,ALT[,ORIENTATION]`` (ORIENTATION: Skybrush's, the bearing of the
    show's X axis)."""
    parts = text.split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--origin must be LAT,LON,ALT[,ORIENTATION] in degrees and metres, not {text!r}") \
            from None
    if len(values) not in (3, 4):
        raise argparse.ArgumentTypeError(
            f"--origin must be LAT,LON,ALT[,ORIENTATION], not {len(values)} numbers")
    keys = ("lat", "lon", "alt", "heading_deg")
    for k, v in zip(keys, values, strict=False):
        problem = ORIGIN_RANGES[k].problem("orientation" if k == "heading_deg" else k, v)
        if problem:
            raise argparse.ArgumentTypeError(f"--origin: {problem}")
    return OriginOption(*values)


def takeoff_altitude(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--takeoff-altitude must be metres, not {text!r}") \
            from None
    problem = TAKEOFF_ALTITUDE.problem("--takeoff-altitude", value)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return value


def smooth_tolerance(text: str) -> float:
    """``--smooth TOL``: metres, more than 0."""
    from groundctl.skybrush.smooth import TOLERANCE
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--smooth must be a tolerance in metres, not "
                                         f"{text!r}") from None
    problem = TOLERANCE.problem("--smooth", value)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return value


def add_import_options(p: argparse.ArgumentParser) -> None:
    """``--origin``, ``--takeoff-altitude``, ``--repair``, ``--smooth``: for a ``.skyc`` or
    CSV show."""
    p.add_argument("--origin", type=origin, default=None,
                   metavar="LAT,LON,ALT[,ORIENTATION]",
                   help="for a Skybrush show (.skyc, CSV): where its frame stands, "
                        "overriding the file's environment.location: the origin (degrees, "
                        "metres above mean sea level) and Skybrush's orientation, the "
                        "bearing of the show's X axis (default: the file's, else 0). "
                        "Without either, the bundled shows' field, "
                        f"{DEFAULT_ORIGIN.lat},{DEFAULT_ORIGIN.lon},{DEFAULT_ORIGIN.alt:g}")
    p.add_argument("--takeoff-altitude", type=takeoff_altitude, default=None, metavar="M",
                   help="for a Skybrush show: the height groundctl takes off to before the "
                        "show's trajectories begin (default: the lowest drone's height "
                        "once every drone is up and at rest)")
    p.add_argument("--repair", action="store_true",
                   help="for a Skybrush show: re-plan only the stretches in conflict (SCP, "
                        "the other drones as moving obstacles), keep the rest")
    p.add_argument("--limits", dest="limits_file", type=Path, default=None, metavar="FILE",
                   help="for a Skybrush show: the envelope your vehicles fly, from the "
                        "[limits] table of FILE (a show file, or one with only that table); "
                        "each key it gives wins over the show's settings.validation and "
                        "groundctl's defaults")
    p.add_argument("--smooth", type=smooth_tolerance, default=None, metavar="TOL",
                   help="for a Skybrush show: round the corners of its trajectories (a "
                        "velocity that changes at once, as between straight segments) "
                        "within TOL metres of the show's path and its acceleration and speed "
                        "limits; says per drone what changed, and each corner it cannot round")


def _origin_note(result: ImportResult, quiet: bool) -> None:
    """Where the show stands, always in one line (an operator must never find out in the
    air that a show turned), and one more when ``--origin`` overrides the file's."""
    if quiet or result.placement is None:
        return
    loc = result.source.location
    if result.placement.source == "--origin" and loc is not None:
        print(f"note: --origin overrides the show's own placement ({loc.lat:.7f},"
              f"{loc.lon:.7f}, its X axis at bearing {loc.orientation_deg:g} deg)",
              file=sys.stderr)
    print(f"note: {result.placement.line()}", file=sys.stderr)


def _import(args: argparse.Namespace, path: Path) -> ImportResult:
    from groundctl.skybrush.importing import import_show

    return import_show(path, getattr(args, "origin", None),
                       takeoff_altitude=getattr(args, "takeoff_altitude", None),
                       do_repair=getattr(args, "repair", False),
                       smooth=getattr(args, "smooth", None),
                       operator_limits=_operator_limits(args))


def _operator_limits(args: argparse.Namespace) -> dict[str, object] | None:
    """``--limits FILE``: the Limits fields its [limits] table gives (None: not given)."""
    path = getattr(args, "limits_file", None)
    if path is None:
        return None
    from groundctl.show.loader import load_limits_file
    return load_limits_file(path)


# -- groundctl plan -------------------------------------------------------------------------


def refuse_for_plan(path: Path) -> None:
    """WrongFileKind unless ``path`` is something ``groundctl plan`` reads."""
    kind = sniff(path)
    if kind is Kind.PLAN:
        raise WrongFileKind(path, kind.value, "a show", "'groundctl plan' reads a show file "
                            "(TOML), a Skybrush .skyc or a Skybrush CSV export; re-verify a "
                            f"plan with 'groundctl check {path}'")
    if kind is Kind.ZIP:
        from groundctl.errors import ImportedShowError
        from groundctl.files import FileProblem
        from groundctl.skybrush.archive import ArchiveProblem, open_zip
        try:
            open_zip(path).close()
        except (ArchiveProblem, FileProblem) as exc:
            raise ImportedShowError(path, f"a zip archive groundctl does not open: {exc}") \
                from None
    if kind in (Kind.ZIP, Kind.DIRECTORY):
        raise WrongFileKind(path, kind.value, "a show", "'groundctl plan' reads a show file "
                            "(TOML), a Skybrush .skyc (a zip with show.json) or a Skybrush "
                            "CSV export (a folder or zip of .csv files)")


def is_import(path: Path) -> bool:
    return is_skybrush(path)


def run_plan(args: argparse.Namespace) -> int:
    """``groundctl plan SHOW.skyc|CSV [-o OUT.skyc|OUT.npz] [--repair]``."""
    path = Path(args.show)
    result = _import(args, path)
    _origin_note(result, args.json)
    plan = result.plan
    out = Path(args.output) if args.output else path.with_name(path.stem + ".plan.npz")
    written = None
    if out.suffix.lower() == ".skyc":
        from groundctl.skybrush.importing import export_skyc
        written = str(export_skyc(plan, out, result.placement))
    else:
        why = result.imported.fits_plan_file
        if why is None:
            written = str(plan.save(out))
    o = result.verification.overall
    report = {
        "source": str(path), "show": plan.show_name, "drones": plan.drones,
        "duration_s": plan.duration, "takeoff_altitude_m": plan.takeoff_altitude,
        "show_time_offset_s": result.imported.t0 - result.imported.climb_s,
        "conflicts": [{"drones": [c.a + 1, c.b + 1], "time_s": c.time,
                       "distance_m": c.distance, "from_s": c.start, "to_s": c.end}
                      for c in result.conflicts],
        "repaired": None if result.repaired is None else [
            {"drones": [d + 1 for d in w.drones], "from_s": w.start, "to_s": w.end}
            for w in result.repaired.windows],
        "remaining_conflicts": None if result.repaired is None
        else len(result.repaired.remaining),
        "placement": None if result.placement is None else {
            "lat": plan.origin.lat, "lon": plan.origin.lon, "alt": plan.origin.alt,
            "orientation_deg": orientation_of(plan.origin.heading_deg),
            "source": result.placement.source,
            "altitude_known": result.placement.altitude_known},
        "min_separation_m": o.min_separation, "max_speed_mps": o.max_speed_h,
        "max_accel_mps2": o.max_accel, "violations": result.lines(), "safe": result.safe,
        "written": written,
        "smoothed": None if result.smoothing is None else result.smoothing.report(),
    }
    if args.json:
        json.dump(report, sys.stdout)
        sys.stdout.write("\n")
    else:
        for line in result.lines():
            print(line)
        verdict = "SAFE" if result.safe else "UNSAFE"
        print(f"{verdict}: {path}: {plan.drones} drones, {plan.duration:.1f} s, "
              f"{len(result.conflicts)} conflicts, min separation {o.min_separation:.3f} m, "
              f"max speed {o.max_speed_h:.2f} m/s, max accel {o.max_accel:.2f} m/s^2")
        if written:
            print(f"written to {written}")
        elif result.imported.fits_plan_file:
            print(f"no plan file written: {result.imported.fits_plan_file} "
                  f"(-o SHOW.skyc writes a .skyc)")
    return EXIT_OK if result.safe else EXIT_UNSAFE


# -- groundctl check ----------------------------------------------------------------------


def refuse_for_check(path: str | Path) -> None:
    """WrongFileKind if ``path`` is a show (TOML or Skybrush) rather than a plan file."""
    kind = sniff(path)
    if kind is Kind.TOML_SHOW:
        raise WrongFileKind(path, kind.value, "a plan file", "'groundctl check' re-verifies "
                            "a plan written by 'groundctl plan' (.npz): plan it with "
                            f"'groundctl plan {path}' (which verifies it too)")
    if kind.skybrush:
        raise WrongFileKind(path, kind.value, "a plan file", "'groundctl check' re-verifies "
                            f"a groundctl plan (.npz): verify it with 'groundctl plan {path}' "
                            "(--repair re-plans its conflicts)")


# -- groundctl dry-run --------------------------------------------------------------------


def flight_plan(args: argparse.Namespace) -> Plan:
    """The plan a flying command flies for a Skybrush show; UnsafePlan listing every
    conflict unless it is safe (or ``--repair`` made it so)."""
    quiet = getattr(args, "quiet", False)
    result = _import(args, Path(args.show))
    _origin_note(result, quiet)
    if getattr(args, "real_vehicles", False) and result.placement is not None \
            and not result.placement.altitude_known:
        # Real vehicles fly the show frame at its altitude above sea level: a stand-in
        # puts the show tens or hundreds of metres above (or below) the field.
        raise ImportedShowError(Path(args.show), "the show gives no altitude above sea level "
                                "(no environment.location, or one without it): give "
                                "--origin LAT,LON,ALT[,ORIENTATION] with the field's")
    if not result.safe:
        raise UnsafePlan(result.lines())
    if not quiet:
        for line in result.lines():
            print(line, file=sys.stderr)
        print(f"imported {result.plan.drones} drones, {result.plan.duration:.1f} s of show "
              f"from {args.show}", file=sys.stderr, flush=True)
    return result.plan
