"""Reading input files that may be hostile: regular files only, of bounded size.

A show file, a point file or a plan file named by someone else can be a FIFO
(opening it blocks for ever), ``/dev/zero`` (reading it never ends), a
directory, or gigabytes.  These helpers open without blocking, look at what
was opened (not at the name, which may be swapped in between), refuse
anything but a regular file, and never read more than the limit.

Problems are :class:`FileProblem` (a message without the path); callers turn
them into their own :class:`~groundctl.errors.GroundctlError` with the path
and the place in the file.
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

#: One mebibyte, for limits.
MiB = 1 << 20


@dataclass(frozen=True)
class FileProblem(Exception):
    """Why a file cannot be read; the message names neither the path nor the contents."""

    message: str
    """What is wrong: ``not a regular file (a FIFO)``, ``no such file``."""
    missing: bool = False
    """True if nothing exists at the path."""

    def __str__(self) -> str:
        return self.message


def size_text(n: float) -> str:
    """``3.2 MiB``, ``512 bytes``: a size for a message."""
    if n < 1024:
        return f"{int(n)} bytes"
    for unit in ("KiB", "MiB", "GiB", "TiB"):
        n /= 1024
        if n < 1024 or unit == "TiB":
            return f"{n:.1f} {unit}"
    raise AssertionError("unreachable")


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a file"


def open_regular_file(path: str | Path, max_bytes: int) -> BinaryIO:
    """``path`` opened for reading if it is a regular file of at most ``max_bytes``.

    Opened with ``O_NONBLOCK`` so a FIFO does not block, then checked with
    ``fstat`` on the descriptor itself.  The caller closes the file.
    """
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise FileProblem("no such file", missing=True) from None
    except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the name
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise FileProblem(f"cannot read the file: {why}") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise FileProblem(f"not a regular file ({_kind(info.st_mode)})")
        if info.st_size > max_bytes:
            raise FileProblem(f"is {size_text(info.st_size)}, more than the "
                              f"{size_text(max_bytes)} allowed")
        if hasattr(os, "O_NONBLOCK"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_regular_file(path: str | Path, max_bytes: int) -> bytes:
    """The bytes of ``path`` if it is a regular file of at most ``max_bytes``.

    Reads at most ``max_bytes + 1`` bytes, so a file that grows after the size
    check is still refused.
    """
    with open_regular_file(path, max_bytes) as fh:
        try:
            data = fh.read(max_bytes + 1)
        except OSError as exc:
            raise FileProblem(f"cannot read the file: {exc.strerror or exc}") from None
    if len(data) > max_bytes:
        raise FileProblem(f"is more than the {size_text(max_bytes)} allowed")
    return data
