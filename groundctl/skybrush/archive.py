"""A zip from anywhere (``.skyc``, a zipped CSV export), read with bounded memory.

Before ``zipfile`` reads the central directory, its size and entry count are
taken from the end record and bounded; every member's name is checked (no
absolute paths, no ``..``, no drive letters, no backslashes: nothing is ever
extracted, but a name that tries to leave the archive says what the file is);
its declared uncompressed size is checked against the limits before anything
is decompressed, and reading stops one byte past the limit whatever the
header claimed (a member that inflates beyond its declared size is refused).
"""

from __future__ import annotations

import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import BinaryIO

from groundctl.files import MiB, size_text

#: Largest archive read at all.
MAX_ARCHIVE_BYTES = 256 * MiB
#: Most members: a CSV per drone of the largest fleet, and room for a few more.
MAX_MEMBERS = 1100
#: Largest central directory read: MAX_MEMBERS entries of a few hundred bytes.
MAX_DIRECTORY_BYTES = 1 * MiB
#: Largest member, uncompressed.
MAX_MEMBER_BYTES = 64 * MiB
#: Largest sum of the members read, uncompressed.
MAX_TOTAL_BYTES = 256 * MiB


class ArchiveProblem(ValueError):
    """Why an archive cannot be read (the message names neither path nor contents)."""


@dataclass(frozen=True)
class Member:
    """One member of the archive, as its directory entry declares it."""

    name: str
    size: int
    """Declared uncompressed size, bytes."""
    info: zipfile.ZipInfo


def is_zip(head: bytes) -> bool:
    """True if ``head`` (the first bytes of a file) starts a zip archive."""
    return head[:4] in (b"PK\x03\x04", b"PK\x05\x06")


def _end_record(fh: BinaryIO) -> None:
    size = fh.seek(0, 2)
    tail_len = min(size, 22 + 0xFFFF)
    fh.seek(size - tail_len)
    tail = fh.read(tail_len)
    at = tail.rfind(b"PK\x05\x06")
    if at < 0 or at + 22 > len(tail):
        raise ArchiveProblem("not a zip archive")
    entries = int.from_bytes(tail[at + 10:at + 12], "little")
    directory = int.from_bytes(tail[at + 12:at + 16], "little")
    if entries > MAX_MEMBERS:
        raise ArchiveProblem(f"the archive lists {entries} members, more than the "
                             f"{MAX_MEMBERS} a show has")
    if directory > MAX_DIRECTORY_BYTES:
        raise ArchiveProblem(f"the archive's directory is {size_text(directory)}, more than "
                             f"the {size_text(MAX_DIRECTORY_BYTES)} a show needs")
    fh.seek(0)


def _safe_name(name: str) -> bool:
    if not name or "\\" in name or "\x00" in name or name.startswith("/"):
        return False
    parts = PurePosixPath(name).parts
    return not any(p == ".." for p in parts) and not (len(name) > 1 and name[1] == ":")


class SafeZip:
    """An open archive whose directory passed the checks; read members with :meth:`read`."""

    def __init__(self, fh: BinaryIO) -> None:
        self._fh = fh
        _end_record(fh)
        try:
            self._zf = zipfile.ZipFile(fh)
        except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError):
            raise ArchiveProblem("not a zip archive (a damaged directory)") from None
        self._read_total = 0
        infos = self._zf.infolist()
        if len(infos) > MAX_MEMBERS:
            raise ArchiveProblem(f"{len(infos)} members, more than the {MAX_MEMBERS} a show has")
        members: dict[str, Member] = {}
        total = 0
        for info in infos:
            name = info.filename
            if not _safe_name(name):
                raise ArchiveProblem(f"member name {name[:80]!r} points outside the archive")
            if info.flag_bits & 0x1:
                raise ArchiveProblem(f"member {name[:80]!r} is encrypted")
            if info.file_size > MAX_MEMBER_BYTES:
                raise ArchiveProblem(f"member {name[:80]!r} declares "
                                     f"{size_text(info.file_size)} uncompressed, more than "
                                     f"{size_text(MAX_MEMBER_BYTES)}")
            if name in members:
                raise ArchiveProblem(f"member {name[:80]!r} appears twice")
            total += info.file_size
            members[name] = Member(name, info.file_size, info)
        if total > MAX_TOTAL_BYTES:
            raise ArchiveProblem(f"the members declare {size_text(total)} uncompressed, more "
                                 f"than {size_text(MAX_TOTAL_BYTES)}")
        self.members = members

    def close(self) -> None:
        self._zf.close()
        self._fh.close()

    def __enter__(self) -> SafeZip:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def read(self, name: str, limit: int = MAX_MEMBER_BYTES) -> bytes:
        """The member's bytes, at most ``limit`` (and its declared size) of them."""
        m = self.members[name]
        if m.size > limit:
            raise ArchiveProblem(f"member {name[:80]!r} is {size_text(m.size)}, more than "
                                 f"{size_text(limit)}")
        try:
            with self._zf.open(m.info) as f:
                data = f.read(m.size + 1)
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, RuntimeError,
                NotImplementedError):
            raise ArchiveProblem(f"member {name[:80]!r} is corrupt") from None
        if len(data) != m.size:
            raise ArchiveProblem(f"member {name[:80]!r} does not hold the size its header "
                                 "declares")
        self._read_total += len(data)
        if self._read_total > MAX_TOTAL_BYTES:
            raise ArchiveProblem(f"more than {size_text(MAX_TOTAL_BYTES)} uncompressed")
        return data


def open_zip(path: str | Path) -> SafeZip:
    """The archive at ``path`` (a regular file of at most MAX_ARCHIVE_BYTES); FileProblem
    or ArchiveProblem."""
    from groundctl.files import open_regular_file

    fh = open_regular_file(path, MAX_ARCHIVE_BYTES)
    try:
        return SafeZip(fh)
    except BaseException:
        fh.close()
        raise
