"""Where a Skybrush show stands when imported: the ``--origin`` option's value and the
stand-in when neither it nor the file places the show.  Apart from
:mod:`.importing` so that the command line can take ``--origin`` without loading the
importer (and with it the planner and the verifier)."""

from __future__ import annotations

from dataclasses import dataclass

from groundctl.show.model import GeoOrigin
from groundctl.skybrush.model import heading_of

#: Where an imported show is anchored when neither the file (``environment.location``)
#: nor ``--origin`` places it: the bundled shows' field, Skybrush's orientation 0 (its X
#: axis north; Skybrush Live's default).
DEFAULT_ORIGIN = GeoOrigin(lat=47.3977, lon=8.5456, alt=488.0, heading_deg=heading_of(0.0))


@dataclass(frozen=True)
class OriginOption:
    """``--origin LAT,LON,ALT[,ORIENTATION]`` for a Skybrush show: ORIENTATION is
    Skybrush's (the bearing of the show's X axis, as Skybrush Live shows it)."""

    lat: float
    lon: float
    alt: float
    orientation_deg: float | None = None
    """None: the file's orientation, or 0."""
