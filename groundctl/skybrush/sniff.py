"""What a file given to a command is: a show, a plan, a Skybrush show, or something else.

Read with the same care as the files themselves: a regular file (or a
directory) only, at most a few KiB of it and a zip's directory (bounded by
:mod:`.archive`), never a member's contents.
"""

from __future__ import annotations

import enum
import re
from pathlib import Path

from groundctl.files import FileProblem, MiB, open_regular_file
from groundctl.skybrush.archive import ArchiveProblem, SafeZip, is_zip

#: A show file's ``[show]`` table header (or its formations), on a line of its own.
_SHOW_TABLE = re.compile(r"^[ \t]*\[(?:show|\[formation\])\][ \t]*(?:#.*)?$", re.MULTILINE)


class Kind(enum.Enum):
    """The kinds of file the commands tell apart; the value is how messages name them."""

    MISSING = "missing"
    TOML_SHOW = "a show file (TOML)"
    PLAN = "a groundctl plan file (.npz)"
    SKYC = "a Skybrush compiled show (.skyc)"
    CSV_DIR = "a Skybrush CSV export (a folder of .csv files)"
    CSV_ZIP = "a Skybrush CSV export (a zip of .csv files)"
    ZIP = "a zip archive that is neither a plan nor a Skybrush show"
    DIRECTORY = "a directory without .csv files"
    TEXT = "a text file"
    BINARY = "binary data"
    SPECIAL = "not a regular file"

    @property
    def skybrush(self) -> bool:
        return self in (Kind.SKYC, Kind.CSV_DIR, Kind.CSV_ZIP)


def sniff(path: str | Path) -> Kind:
    """The kind of the file (or directory) at ``path``."""
    p = Path(path)
    try:
        if p.is_dir():
            try:
                has_csv = any(c.suffix.lower() == ".csv" for c in p.iterdir())
            except OSError:
                return Kind.DIRECTORY
            return Kind.CSV_DIR if has_csv else Kind.DIRECTORY
        fh = open_regular_file(p, 256 * MiB)
    except FileProblem as exc:
        return Kind.MISSING if exc.missing else Kind.SPECIAL
    except OSError:
        return Kind.SPECIAL
    with fh:
        head = fh.read(4096)
        if is_zip(head):
            fh.seek(0)
            try:
                zf = SafeZip(fh)  # closes nothing here: ``with fh`` does
            except ArchiveProblem:
                return Kind.SKYC if p.suffix.lower() == ".skyc" else Kind.ZIP
            names = list(zf.members)
            if "show.json" in names:
                return Kind.SKYC
            if names and all(n.endswith(".npy") for n in names):
                return Kind.PLAN
            if any(n.lower().endswith(".csv") for n in names):
                return Kind.CSV_ZIP
            return Kind.SKYC if p.suffix.lower() == ".skyc" else Kind.ZIP
        if p.suffix.lower() == ".skyc":
            return Kind.SKYC  # its reader says what is wrong with it
        fh.seek(0)
        data = fh.read(1 * MiB + 1)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        return Kind.BINARY
    # Never parsed here: tomllib's time grows with the square of a dotted key's length,
    # which the show loader bounds before it parses (see groundctl.show.loader).
    return Kind.TOML_SHOW if _SHOW_TABLE.search(text) else Kind.TEXT


def is_skybrush(path: str | Path) -> bool:
    """True for a ``.skyc`` (or anything named so) and a CSV export (folder or zip)."""
    return Path(path).suffix.lower() == ".skyc" or sniff(path).skybrush
