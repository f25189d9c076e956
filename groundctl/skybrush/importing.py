"""A Skybrush show in, verified (and repaired); a plan out as ``.skyc``: what the CLI calls."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace
from pathlib import Path
from typing import Any

from groundctl.errors import ImportedShowError
from groundctl.plan.plan import Plan
from groundctl.plan.verify import Verification, verify
from groundctl.show.model import GeoOrigin, Limits
from groundctl.skybrush.conflicts import Conflict, find_conflicts
from groundctl.skybrush.convert import (
    ConversionError,
    Imported,
    limits_for,
    plan_to_sky,
    sky_to_plan,
)
from groundctl.skybrush.csvshow import read_csv_show
from groundctl.skybrush.model import SkyShow, heading_of, orientation_of
from groundctl.skybrush.origin import DEFAULT_ORIGIN, OriginOption
from groundctl.skybrush.reader import read_skyc
from groundctl.skybrush.repair import Repair, repair
from groundctl.skybrush.smooth import Smoothing, smooth_show
from groundctl.skybrush.sniff import Kind, sniff
from groundctl.skybrush.writer import write_skyc


@dataclass(frozen=True)
class Placement:
    """Where an imported show stands, and where that came from."""

    origin: GeoOrigin
    """The show frame's geodetic origin and heading."""
    source: str
    """``"code"`` (a GeoOrigin given in code, used as it is), ``"--origin"``, ``"file"``
    (the show's ``environment.location``) or ``"default"`` (:data:`DEFAULT_ORIGIN`)."""
    altitude_known: bool
    """The origin's altitude above sea level was given (by the operator, the file or
    code), not :data:`DEFAULT_ORIGIN`'s stand-in: real vehicles fly only such a show."""

    def line(self) -> str:
        """One line: where the show stands and which way its X axis points."""
        o = self.origin
        orientation = orientation_of(o.heading_deg)
        where = {"code": "as given", "--origin": "from --origin",
                 "file": "from the show's environment.location",
                 "default": "not placed by the show (no environment.location): the bundled "
                            "shows' field; give --origin LAT,LON,ALT[,ORIENTATION]"}[self.source]
        alt = f"{o.alt:g} m" if self.altitude_known else \
            f"{o.alt:g} m (a stand-in: the show gives no altitude above sea level)"
        return (f"placed at {o.lat:.7f},{o.lon:.7f}, z = 0 at {alt}, its X axis at bearing "
                f"{orientation:g} deg ({where})")


def place(show: SkyShow, given: GeoOrigin | OriginOption | None) -> Placement:
    """The show frame's geodetic origin and heading: ``given``, else the file's
    ``environment.location``, else :data:`DEFAULT_ORIGIN`.  Coordinates are kept as the
    file has them: only the heading carries Skybrush's orientation
    (:func:`~groundctl.skybrush.model.heading_of`)."""
    loc = show.location
    if isinstance(given, GeoOrigin):
        return Placement(given, "code", True)
    if isinstance(given, OriginOption):
        orientation = given.orientation_deg if given.orientation_deg is not None else \
            (loc.orientation_deg if loc is not None else 0.0)
        return Placement(GeoOrigin(given.lat, given.lon, given.alt, heading_of(orientation)),
                         "--origin", True)
    if loc is not None:
        alt = loc.amsl if loc.amsl is not None else DEFAULT_ORIGIN.alt
        return Placement(GeoOrigin(loc.lat, loc.lon, alt, loc.heading_deg), "file",
                         loc.amsl is not None)
    return Placement(DEFAULT_ORIGIN, "default", False)


@dataclass(frozen=True)
class ImportResult:
    """An imported show, its check, and its repair if one was asked for."""

    source: SkyShow
    """The show as read."""
    imported: Imported
    """Its conversion to a plan (before any repair)."""
    conflicts: tuple[Conflict, ...]
    """Every separation conflict found in it."""
    repaired: Repair | None
    """What ``--repair`` did (None: not asked, or nothing to repair)."""
    verification: Verification
    """The verifier's verdict on :attr:`plan`."""
    problems: tuple[str, ...] = field(default=())
    """Violations the verifier does not see: velocity jumps."""
    placement: Placement | None = None
    """Where the show stands and where that came from (:func:`place`)."""
    smoothing: Smoothing | None = None
    """What ``--smooth`` did (None: not asked); :attr:`imported` is then the smoothed show's
    conversion, and its corners not rounded are the :attr:`problems`."""

    @property
    def plan(self) -> Plan:
        return self.repaired.plan if self.repaired is not None else self.imported.plan

    @property
    def safe(self) -> bool:
        remaining = self.repaired.remaining if self.repaired is not None else self.conflicts
        return self.verification.safe and not remaining and not self.problems

    def lines(self) -> list[str]:
        """Every conflict and violation, one line each (times on the plan's clock and, in
        brackets, the Skybrush show's)."""
        names = tuple(d.name for d in self.source.drones)
        limit = self.imported.plan.limits.min_separation
        off = self.imported.t0 - self.imported.climb_s
        out = [c.line(limit, names) + f" [show time {c.time + off:.2f} s]"
               for c in self.conflicts]
        if self.smoothing is not None:
            out += self.smoothing.lines()
        out += [f"violation: {p}" for p in self.problems]
        if self.repaired is not None:
            for w in self.repaired.windows:
                out.append(f"repaired: drones {', '.join(str(d + 1) for d in w.drones)} "
                           f"re-planned from t = {w.start:.2f} to {w.end:.2f} s [show time "
                           f"{w.start + off:.2f} to {w.end + off:.2f} s]")
            out += ["still " + c.line(limit, names) for c in self.repaired.remaining]
        listed = self.repaired.remaining if self.repaired is not None else self.conflicts
        out += [f"violation: {v}" for v in self.verification.violations
                if not (listed and v.startswith("drones ") and " apart at t = " in v)]
        return out


def read_any(path: str | Path) -> SkyShow:
    """A ``.skyc`` or a CSV export, by what the file is."""
    kind = sniff(path)
    if kind in (Kind.CSV_DIR, Kind.CSV_ZIP):
        return read_csv_show(path)
    return read_skyc(path)


def import_show(path: str | Path, origin: GeoOrigin | OriginOption | None = None, *,
                limits: Limits | None = None, takeoff_altitude: float | None = None,
                do_repair: bool = False, smooth: float | None = None,
                operator_limits: Mapping[str, Any] | None = None) -> ImportResult:
    """Read, convert, check and (with ``do_repair``) repair the Skybrush show at ``path``,
    placed by ``origin`` or the file (:func:`place`); with ``smooth`` (m), first round its
    corners within that tolerance (:mod:`groundctl.skybrush.smooth`).  The limits are
    ``limits`` (groundctl's defaults), then the show's ``settings.validation``, then
    ``operator_limits`` (Limits fields: the envelope the operator's vehicles fly,
    ``--limits FILE``), each over the one before."""
    show = read_any(path)
    lim = limits_for(show, limits or Limits())
    if operator_limits:
        lim = dc_replace(lim, **operator_limits)
        if lim.max_alt <= lim.min_alt:
            raise ImportedShowError(path, f"--limits: max_altitude {lim.max_alt:g} m is not "
                                          f"above min_altitude {lim.min_alt:g} m")
    placement = place(show, origin)
    where = placement.origin
    smoothing = None
    try:
        imported = sky_to_plan(show, where, lim, takeoff_altitude)
        if smooth is not None:
            # Rounded between the instants the plan begins and ends (found on the show as
            # read), so that both stay where they were.
            smoothing = smooth_show(show, lim, smooth, imported.t0, imported.t_end)
            imported = sky_to_plan(smoothing.show, where, lim, takeoff_altitude)
    except (ConversionError, ValueError) as exc:
        raise ImportedShowError(path, str(exc)) from None
    conflicts = tuple(find_conflicts(imported.plan.trajectories, lim.min_separation))
    fixed = repair(imported.plan, list(conflicts)) if do_repair and conflicts else None
    plan = fixed.plan if fixed is not None else imported.plan
    problems = imported.jumps
    if smoothing is not None:
        # Every jump left is a corner not rounded, which says why: one line each.
        problems = smoothing.problems() or imported.jumps
    return ImportResult(source=show, imported=imported, conflicts=conflicts, repaired=fixed,
                        verification=verify(plan), problems=problems, smoothing=smoothing,
                        placement=placement)


def export_skyc(plan: Plan, path: str | Path, placement: Placement | None = None) -> Path:
    """Write ``plan`` as a ``.skyc`` at ``path``; ``placement``: where an imported show's
    origin came from (a stand-in origin or altitude is not written as the show's own)."""
    sky, _ = plan_to_sky(plan, placed=placement is None or placement.source != "default",
                         altitude=placement is None or placement.altitude_known)
    return write_skyc(sky, path)
