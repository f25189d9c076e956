"""Hostile show and plan files, and a runner that feeds each one to the real CLI.

Every case writes its files into a directory of its own and returns the
``groundctl`` command line that reads them.  :func:`run_case` runs that
command line through :func:`groundctl.cli.main` in a forked child (fast: no
interpreter start-up per case) with its address space capped and a deadline,
so a case that would allocate 74 GiB or hang on a FIFO is measured as a crash
instead of taking the machine or the test run with it.

What every case must give (``sitl_tests/test_hostile_files.py``,
``benchmarks/hostile_files.py``): a non-zero exit, no traceback, exactly one
line on stderr, and none of the case's ``forbidden`` text (file contents) in it.
"""

from __future__ import annotations

import json
import os
import resource
import signal
import sys
import time
import traceback
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

#: A valid 4-drone show: plans in a fraction of a second, safe.
BASE_SHOW = """\
[show]
name = "base"
drones = 4
takeoff_altitude = 3.0

[origin]
lat = 47.0
lon = 8.0
alt = 400.0

[limits]
min_separation = 1.5
max_altitude = 40.0

[takeoff]
layout = "grid"
spacing = 3.0
columns = 2

[[formation]]
name = "line"
shape = "line"
center = [0.0, 0.0, 10.0]
size = 9.0
transition = 10.0
hold = 1.0
color = "#ff0000"
"""

#: The secret a hostile point file would leak if an error echoed file contents.
SECRET = "root:x:0:0:s3cr3t-token"

Argv = list[str]


@dataclass(frozen=True)
class Case:
    """One hostile input: how to write it and which command reads it."""

    name: str
    """Test id."""
    make: Callable[[Path], Argv]
    """Writes the case's files into the (empty) directory given; returns the argv."""
    forbidden: tuple[str, ...] = ()
    """Text the error line must not contain (the contents of files it points at)."""


@dataclass(frozen=True)
class Outcome:
    """What one run of the CLI gave."""

    exit_code: int | None
    """The exit code (None if it died by a signal or was killed at the deadline)."""
    stdout: str
    stderr: str
    seconds: float
    timed_out: bool = False
    signal: int | None = None

    @property
    def crashed(self) -> bool:
        """Died by a signal (a segfault, killed at the deadline) instead of exiting."""
        return self.exit_code is None

    @property
    def traceback(self) -> bool:
        return "Traceback (most recent call last)" in self.stderr

    @property
    def lines(self) -> list[str]:
        return self.stderr.splitlines()

    def one_line_refusal(self, forbidden: tuple[str, ...] = ()) -> bool:
        """Non-zero exit, no traceback, exactly one line on stderr, nothing forbidden in it."""
        return (self.exit_code not in (None, 0) and not self.traceback
                and len(self.lines) == 1 and not any(f in self.stderr for f in forbidden))


# -- running --------------------------------------------------------------------------------


def _address_space() -> int:
    """This process's virtual size in bytes (the child starts as a copy of it)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    return 0


@cache
def _warm() -> None:
    """Import what the commands import lazily, once, before the first fork: each child
    then starts with it (a case takes milliseconds instead of an import's 0.2 s)."""
    import groundctl.cli
    import groundctl.commands.sim
    import groundctl.flight.dryrun
    import groundctl.plan.planner
    import groundctl.plan.provenance
    import groundctl.plan.verify
    import groundctl.record.recording
    import groundctl.show.loader

    groundctl.cli.build_parser()
    del groundctl


def run_case(argv: Argv, cwd: Path, timeout: float = 30.0,
             memory: int = 2 << 30) -> Outcome:
    """``groundctl ARGV`` in a forked child in ``cwd``: at most ``memory`` bytes more than
    this process holds, killed after ``timeout`` s."""
    _warm()
    out, err = cwd / ".stdout", cwd / ".stderr"
    limit = _address_space() + memory
    t0 = time.monotonic()
    pid = os.fork()
    if pid == 0:  # the child: never returns
        code = 1
        try:
            os.setpgid(0, 0)  # its own group: a deadline kills whatever it started too
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
            os.chdir(cwd)
            fd_out = os.open(out, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            fd_err = os.open(err, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            os.dup2(fd_out, 1)
            os.dup2(fd_err, 2)
            sys.stdout = open(1, "w", closefd=False)  # noqa: SIM115 - the child exits below
            sys.stderr = open(2, "w", closefd=False)  # noqa: SIM115
            sys.stdin = open(os.devnull)  # noqa: SIM115
            from groundctl.cli import main
            code = main(argv)
        except SystemExit as exc:  # argparse
            code = exc.code if isinstance(exc.code, int) else 2
        except BaseException:
            traceback.print_exc()  # what the interpreter prints for an uncaught exception
            code = 1
        finally:
            try:
                sys.stdout.flush()
                sys.stderr.flush()
            finally:
                os._exit(code)
    timed_out = False
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() - t0 > timeout:
            os.killpg(pid, signal.SIGKILL)
            _, status = os.waitpid(pid, 0)
            timed_out = True
            break
        time.sleep(0.005)
    seconds = time.monotonic() - t0
    stdout = out.read_text(errors="replace") if out.exists() else ""
    stderr = err.read_text(errors="replace") if err.exists() else ""
    if os.WIFEXITED(status) and not timed_out:
        return Outcome(os.WEXITSTATUS(status), stdout, stderr, seconds)
    return Outcome(None, stdout, stderr, seconds, timed_out,
                   os.WTERMSIG(status) if os.WIFSIGNALED(status) else None)


# -- building blocks ----------------------------------------------------------------------


def write_show(directory: Path, text: str = BASE_SHOW, name: str = "show.toml") -> Path:
    path = directory / name
    path.write_text(text)
    return path


def show_with(**replace: str) -> str:
    """BASE_SHOW with lines replaced: ``show_with(drones="drones = 0")`` swaps the line
    starting with ``drones =``; a key not in it is added to its table ``table__key``."""
    lines = BASE_SHOW.splitlines()
    for key, new in replace.items():
        table, _, bare = key.rpartition("__")
        hits = [i for i, line in enumerate(lines) if line.startswith(f"{bare} =")]
        if hits and not table:
            lines[hits[0]] = new
            continue
        header = f"[{table}]" if table != "formation" else "[[formation]]"
        if header not in lines:
            lines += ["", header]
        lines.insert(lines.index(header) + 1, new)
    return "\n".join(lines) + "\n"


@cache
def _base_plan_files() -> tuple[bytes, dict[str, np.ndarray]]:
    """BASE_SHOW planned once per process: (the plan file's bytes, its arrays)."""
    import tempfile

    from groundctl.plan.planner import plan_show
    from groundctl.show.loader import load_show

    with tempfile.TemporaryDirectory() as tmp:
        show = write_show(Path(tmp))
        plan = plan_show(load_show(show), workers=1).plan
        path = plan.save(Path(tmp) / "show.plan.npz")
        raw = path.read_bytes()
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: np.array(data[k]) for k in data.files}
    return raw, arrays


def base_arrays() -> dict[str, np.ndarray]:
    """A fresh copy of the base plan's arrays (``meta`` as a dict under "meta")."""
    _, arrays = _base_plan_files()
    out: dict[str, Any] = {k: v.copy() for k, v in arrays.items()}
    out["meta"] = json.loads(str(arrays["meta"]))
    return out


def write_plan(directory: Path, arrays: dict[str, Any] | None = None, *,
               name: str = "show.plan.npz", sibling: bool = True) -> Path:
    """The base plan (or ``arrays``) as ``name``; with its show next to it if ``sibling``."""
    if sibling:
        write_show(directory, name=name.removesuffix(".npz").removesuffix(".plan") + ".toml")
    path = directory / name
    if arrays is None:
        path.write_bytes(_base_plan_files()[0])
        return path
    out = dict(arrays)
    if isinstance(out.get("meta"), dict):
        out["meta"] = np.array(json.dumps(out["meta"]))
    with path.open("wb") as fh:
        np.savez_compressed(fh, **out)
    return path


def npy_member(header: str, data: bytes = b"", version: tuple[int, int] = (1, 0)) -> bytes:
    """A raw .npy member: magic, a header dict written by hand, then ``data``."""
    head = header.encode("latin1")
    if version == (1, 0):
        pad = 64 - (10 + len(head) + 1) % 64
        return b"\x93NUMPY\x01\x00" + (len(head) + pad + 1).to_bytes(2, "little") + head \
            + b" " * pad + b"\n" + data
    pad = 64 - (12 + len(head) + 1) % 64
    return b"\x93NUMPY" + bytes(version) + (len(head) + pad + 1).to_bytes(4, "little") + head \
        + b" " * pad + b"\n" + data


def write_zip(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return path


def base_members(skip: tuple[str, ...] = ()) -> dict[str, bytes]:
    """The base plan's zip members, as raw bytes."""
    import io

    raw, _ = _base_plan_files()
    with zipfile.ZipFile(io.BytesIO(raw)) as zf:
        return {n: zf.read(n) for n in zf.namelist() if n.removesuffix(".npy") not in skip}


# -- plan-file cases ----------------------------------------------------------------------


def _plan_case(name: str, edit: Callable[[dict[str, Any]], None],
               command: str = "check", sibling: bool = True) -> Case:
    def make(d: Path) -> Argv:
        arrays = base_arrays()
        edit(arrays)
        path = write_plan(d, arrays, sibling=sibling)
        return _command(command, path)
    return Case(name, make)


def _command(command: str, path: Path, *extra: str) -> Argv:
    if command == "check":
        return ["check", str(path), *extra]
    if command == "dry-run":
        return ["dry-run", str(path), "--no-record", "-q", *extra]
    if command == "fly":
        # Refused while the plan is read, before the port is bound.
        return ["fly", str(path), "--connect", "udp:127.0.0.1:14599", "-q",
                "--connect-timeout", "1", *extra]
    if command == "sim":
        return ["sim", "--show", str(path), *extra]
    return ["plan", str(path), "-o", str(path.with_name("out.plan.npz")), *extra]


def _set(key: str, value: Any) -> Callable[[dict[str, Any]], None]:
    def edit(a: dict[str, Any]) -> None:
        a[key] = value(a[key]) if callable(value) else value
    return edit


def _meta(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    """Set meta["a"]["b"] for path "a.b" (a missing sentinel deletes it)."""
    def edit(a: dict[str, Any]) -> None:
        node = a["meta"]
        *parents, last = path.split(".")
        for p in parents:
            node = node[int(p)] if isinstance(node, list) else node[p]
        if value is _DELETE:
            del node[last]
        elif isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value
    return edit


_DELETE = object()


def _nan_at(key: str, index: tuple[int, ...] | None = None) -> Callable[[dict[str, Any]], None]:
    def edit(a: dict[str, Any]) -> None:
        arr = np.array(a[key], dtype=float)
        if index is None:
            arr[...] = np.nan
        else:
            arr[index] = np.nan
        a[key] = arr
    return edit


def tamper_separation(a: dict[str, Any]) -> None:
    """The issue's plan: limits edited down (to 0.6 m: the issue's 0.2 m is now below the
    floor of what drones can keep, refused for that alone), drones 2 and 1 0.7 m apart."""
    a["meta"]["limits"]["min_separation"] = 0.6
    shift = np.array([0.7, 0.0, 0.0])
    a["home"][1] = a["home"][0] + shift
    a["pos"][1] = a["pos"][0] + shift
    a["vel"][1] = a["vel"][0]
    for key in [k for k in a if k.startswith("goals_")]:
        a[key][1] = a[key][0] + shift


def _raw_plan_case(name: str, members: Callable[[], dict[str, bytes]],
                   command: str = "check") -> Case:
    def make(d: Path) -> Argv:
        write_show(d)
        return _command(command, write_zip(d / "show.plan.npz", members()))
    return Case(name, make)


def _huge_declared() -> dict[str, bytes]:
    # 1,000,000 x 360 x 3 doubles = 8.6 GB declared; a few MB of zeros actually stored.
    m = base_members(skip=("pos",))
    m["pos.npy"] = npy_member("{'descr': '<f8', 'fortran_order': False, "
                              "'shape': (1000000, 360, 3), }", bytes(4 << 20))
    return m


def _member(name: str, header: str, data: bytes = b"",
            version: tuple[int, int] = (1, 0)) -> Callable[[], dict[str, bytes]]:
    def members() -> dict[str, bytes]:
        m = base_members(skip=(name,))
        m[f"{name}.npy"] = npy_member(header, data, version)
        return m
    return members


def _cut_short(name: str) -> Callable[[], dict[str, bytes]]:
    def members() -> dict[str, bytes]:
        m = base_members()
        m[f"{name}.npy"] = m[f"{name}.npy"][: len(m[f"{name}.npy"]) // 2]
        return m
    return members


def _file_case(name: str, write: Callable[[Path], Path], command: str = "check") -> Case:
    def make(d: Path) -> Argv:
        write_show(d)
        return _command(command, write(d))
    return Case(name, make)


def _fifo(d: Path) -> Path:
    path = d / "show.plan.npz"
    os.mkfifo(path)
    return path


def _symlink_to(target: str, name: str) -> Callable[[Path], Path]:
    def write(d: Path) -> Path:
        path = d / name
        path.symlink_to(target)
        return path
    return write


def _bytes(name: str, data: bytes) -> Callable[[Path], Path]:
    def write(d: Path) -> Path:
        path = d / name
        path.write_bytes(data)
        return path
    return write


def _dir(name: str) -> Callable[[Path], Path]:
    def write(d: Path) -> Path:
        path = d / name
        path.mkdir()
        return path
    return write


def _plan_without_digest(d: Path) -> Argv:
    arrays = base_arrays()
    arrays["meta"].pop("show_digest", None)
    return ["check", str(write_plan(d, arrays))]


def _plan_with_other_show(d: Path) -> Argv:
    plan = write_plan(d, sibling=False)
    other = write_show(d, BASE_SHOW.replace('"#ff0000"', '"#00ff00"'), "other.toml")
    return ["check", str(plan), "--show", str(other)]


def plan_cases() -> Iterator[Case]:
    """Hostile plan files (``.npz``): check, dry-run, fly and sim --show read them."""
    yield _plan_case("plan-vel-nan", _nan_at("vel"))
    yield _plan_case("plan-vel-nan-dry-run", _nan_at("vel"), "dry-run")
    yield _plan_case("plan-vel-nan-fly", _nan_at("vel"), "fly")
    yield _plan_case("plan-times-nan", _nan_at("times", (3,)))
    yield _plan_case("plan-times-reversed", _set("times", lambda t: t[::-1].copy()))
    yield _plan_case("plan-times-repeated", _set("times", lambda t: np.r_[t[:2], t[1:-1]]))
    yield _plan_case("plan-pos-inf", _set("pos", lambda p: np.full_like(p, np.inf)))
    yield _plan_case("plan-colors-nan", _nan_at("colors", (0, 1, 0)))
    yield _plan_case("plan-colors-out-of-range", _set("colors", lambda c: c * 300))
    yield _plan_case("plan-color-times-nan", _nan_at("color_times", (1,)))
    yield _plan_case("plan-home-nan", _nan_at("home", (2, 1)), "dry-run")
    yield _plan_case("plan-home-nan-sim", _nan_at("home", (2, 1)), "sim")
    yield _plan_case("plan-goals-nan", _nan_at("goals_0", (0, 0)))
    yield _plan_case("plan-origin-lat-nan", _meta("origin.lat", float("nan")))
    yield _plan_case("plan-origin-alt-huge", _meta("origin.alt", -1e30), "sim")
    yield _plan_case("plan-origin-extra-key", _meta("origin.evil", 1))
    yield _plan_case("plan-origin-missing", _meta("origin", _DELETE))
    yield _plan_case("plan-takeoff-altitude-string", _meta("takeoff_altitude", "high"))
    yield _plan_case("plan-limits-list", _meta("limits", [1, 2, 3]))
    yield _plan_case("plan-limits-nan", _meta("limits.min_separation", float("nan")))
    yield _plan_case("plan-limits-geofence-bad", _meta("limits.geofence", [[0, 0], "x"]))
    yield _plan_case("plan-model-unknown", _meta("model", "rocket"))
    yield _plan_case("plan-mpc-bad", _meta("mpc.horizon_s", 100.0))
    yield _plan_case("plan-format-2", _meta("format", 2))
    yield _plan_case("plan-formations-int", _meta("formations", 7))
    yield _plan_case("plan-formations-empty", _meta("formations", []))
    yield _plan_case("plan-formation-start-nan", _meta("formations.0.start", float("nan")))
    yield _plan_case("plan-formations-too-many", _meta("formations", [
        {"index": i, "name": "x", "start": 0.0, "arrive": 1.0, "end": 1.0}
        for i in range(1, 100_001)]))
    yield _plan_case("plan-show-name-escape", _meta("show_name", "a\nb\x1b[31m"), "dry-run")
    yield _plan_case("plan-show-name-int", _meta("show_name", 5))
    yield _plan_case("plan-show-digest-int", _meta("show_digest", 5))
    yield _plan_case("plan-meta-list", _set("meta", []))
    yield _plan_case("plan-meta-deep-json", _set("meta", "[" * 100_000 + "]" * 100_000))
    yield _plan_case("plan-meta-not-json", _set("meta", "{not json"))
    yield _plan_case("plan-meta-bytes", _set("meta", np.frombuffer(b"abcdefgh", "<f8")))
    yield _plan_case("plan-pos-2d", _set("pos", lambda p: p[..., :2].copy()))
    yield _plan_case("plan-vel-fewer-knots", _set("vel", lambda v: v[:, :-1].copy()))
    yield _plan_case("plan-home-wrong-count", _set("home", lambda h: h[:-1].copy()))
    yield _plan_case("plan-colors-4-channels", _set("colors", lambda c: np.concatenate(
        [c, c[..., :1]], axis=2)))
    yield _plan_case("plan-one-knot", _set("times", lambda t: t[:1].copy()))
    yield _plan_case("plan-pos-complex", _set("pos", lambda p: p.astype(complex)))
    yield _plan_case("plan-pos-int", _set("pos", lambda p: p.astype(np.int64)))
    yield _plan_case("plan-missing-vel", lambda a: a.pop("vel"))
    yield _plan_case("plan-extra-member", _set("evil", np.zeros(3)))
    yield _plan_case("plan-starts-off-home", _set("pos", lambda p: p + np.array([0, 0, 5.0])))
    yield _plan_case("plan-limits-tampered-separation", tamper_separation)
    yield _plan_case("plan-limits-tampered-separation-dry-run", tamper_separation,
                     "dry-run")
    yield _plan_case("plan-limits-tampered-no-show", tamper_separation, sibling=False)
    yield Case("plan-without-show-hash", _plan_without_digest)
    yield Case("plan-from-another-show", _plan_with_other_show)
    yield _raw_plan_case("plan-huge-declared-array", _huge_declared)
    yield _raw_plan_case("plan-huge-declared-array-dry-run", _huge_declared, "dry-run")
    yield _raw_plan_case("plan-object-array", _member(
        "pos", "{'descr': '|O', 'fortran_order': False, 'shape': (2,), }",
        b"\x80\x04\x95\x00\x00\x00\x00\x00\x00\x00\x00."))
    yield _raw_plan_case("plan-npy-version-9", _member(
        "pos", "{'descr': '<f8', 'fortran_order': False, 'shape': (1,), }", bytes(8), (9, 0)))
    yield _raw_plan_case("plan-npy-bad-header", _member("pos", "{'descr': __import__('os')}"))
    yield _raw_plan_case("plan-npy-negative-shape", _member(
        "times", "{'descr': '<f8', 'fortran_order': False, 'shape': (-5,), }"))
    yield _raw_plan_case("plan-npy-truncated-data", _member(
        "times", "{'descr': '<f8', 'fortran_order': False, 'shape': (50,), }", bytes(16)))
    yield _raw_plan_case("plan-member-cut-short", _cut_short("pos"))
    yield _raw_plan_case("plan-zip-many-members", lambda: {
        **base_members(), **{f"goals_{i}.npy": b"" for i in range(5000)}})
    yield _raw_plan_case("plan-member-random-bytes", lambda: {
        **base_members(skip=("meta",)), "meta.npy": os.urandom(4096)})
    yield _raw_plan_case("plan-member-not-npy", lambda: {
        **base_members(), "../../evil.npy": b"x"})
    yield _raw_plan_case("plan-meta-too-long", _member(
        "meta", "{'descr': '<U100000000', 'fortran_order': False, 'shape': (), }"))
    yield _file_case("plan-empty-file", _bytes("show.plan.npz", b""))
    yield _file_case("plan-random-bytes", _bytes("show.plan.npz", os.urandom(2048)))
    yield _file_case("plan-random-bytes-dry-run", _bytes("show.plan.npz", os.urandom(2048)),
                     "dry-run")
    yield _file_case("plan-text", _bytes("show.plan.npz", b"hello"))
    yield _file_case("plan-truncated-zip", lambda d: _bytes(
        "show.plan.npz", _base_plan_files()[0][: len(_base_plan_files()[0]) // 2])(d))
    yield _file_case("plan-corrupt-deflate", lambda d: _bytes(
        "show.plan.npz", _corrupt(_base_plan_files()[0]))(d))
    yield _file_case("plan-fifo", _fifo)
    yield _file_case("plan-fifo-dry-run", _fifo, "dry-run")
    yield _file_case("plan-dev-zero", _symlink_to("/dev/zero", "show.plan.npz"))
    yield _file_case("plan-directory", _dir("show.plan.npz"))
    yield _file_case("plan-missing", lambda d: d / "nothing.plan.npz")


def _corrupt(raw: bytes) -> bytes:
    """The zip with its largest member's compressed bytes scrambled (directory intact)."""
    import io

    with zipfile.ZipFile(io.BytesIO(raw)) as zf:
        info = max(zf.infolist(), key=lambda i: i.compress_size)
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    data = bytearray(raw)
    for i in range(start + 8, start + info.compress_size - 8):
        data[i] ^= 0x5A
    return bytes(data)


# -- show-file cases ----------------------------------------------------------------------


def _show_case(name: str, text: str | Callable[[Path], str], command: str = "plan",
               forbidden: tuple[str, ...] = ()) -> Case:
    def make(d: Path) -> Argv:
        body = text(d) if callable(text) else text
        show = write_show(d, body)
        if command == "check-show":
            return ["check", str(write_plan(d, name="base.plan.npz", sibling=False)),
                    "--show", str(show)]
        return _command(command, show)
    return Case(name, make, forbidden)


def points_file_show(value: str, prepare: Callable[[Path], None] | None = None
                 ) -> Callable[[Path], str]:
    def text(d: Path) -> str:
        if prepare is not None:
            prepare(d)
        return show_with(shape='shape = "points"', size=f"file = {json.dumps(value)}",
                         center="center = [0.0, 0.0, 0.0]")
    return text


def _secret_csv(d: Path) -> None:
    (d / "secret.csv").write_text(f"{SECRET}\n{SECRET}\n")


def _secret_outside(d: Path) -> None:
    (d.parent / f"{d.name}-outside.csv").write_text(f"x,y,z\n{SECRET},0,0\n")


def _fifo_csv(d: Path) -> None:
    os.mkfifo(d / "pipe.csv")


def _link_csv(d: Path) -> None:
    (d / "link.csv").symlink_to("/etc/passwd")


def _big_csv(d: Path) -> None:
    with (d / "big.csv").open("w") as f:
        f.write("x,y,z\n")
        f.write("0,0,0\n" * 400_000)


def _nul_csv(d: Path) -> None:
    (d / "nul.csv").write_bytes(b"x,y,z\n0,\x000,5\n")


def _latin1_csv(d: Path) -> None:
    (d / "latin1.csv").write_bytes(b"x,y,z\n\xe9\xff,0,5\n")


def _many_points_csv(d: Path) -> None:
    rows = "\n".join(f"{i * 2},0,10" for i in range(6000))
    (d / "many.csv").write_text(f"x,y,z\n{rows}\n")


def _drones(n: int) -> str:
    return show_with(drones=f"drones = {n}")


def random_layout_show(n: int, area: float) -> str:
    text = show_with(drones=f"drones = {n}")
    return text.replace('layout = "grid"\nspacing = 3.0\ncolumns = 2',
                        f'layout = "random"\narea = [{area}, {area}]')


def long_show(transitions: int, seconds: float) -> str:
    forms = "".join(f'\n[[formation]]\nname = "f{i}"\nshape = "line"\n'
                    f'center = [0.0, 0.0, {10 + i % 2}.0]\nsize = 9.0\n'
                    f'transition = {seconds}\n' for i in range(transitions))
    return BASE_SHOW + forms


def show_cases() -> Iterator[Case]:
    """Hostile show files (TOML): plan, dry-run, sim --show and check --show read them."""
    forbidden = (SECRET, "root:", "/bin/")
    yield _show_case("points-file-etc-passwd", points_file_show("../../../../../../etc/passwd"),
                     forbidden=forbidden)
    yield _show_case("points-file-etc-shadow", points_file_show("/etc/shadow"),
                     forbidden=forbidden)
    yield _show_case("points-file-etc-passwd-dry-run",
                     points_file_show("../../../../../../etc/passwd"), "dry-run",
                     forbidden=forbidden)
    yield _show_case("points-file-outside-sibling", lambda d: points_file_show(
        f"../{d.name}-outside.csv", _secret_outside)(d), forbidden=forbidden)
    yield _show_case("points-file-secret-inside", points_file_show("secret.csv", _secret_csv),
                     forbidden=forbidden)
    yield _show_case("points-file-dev-zero", points_file_show("/dev/zero"))
    yield _show_case("points-file-fifo", points_file_show("pipe.csv", _fifo_csv))
    yield _show_case("points-file-fifo-sim", points_file_show("pipe.csv", _fifo_csv), "sim")
    yield _show_case("points-file-symlink-out", points_file_show("link.csv", _link_csv),
                     forbidden=forbidden)
    yield _show_case("points-file-directory", points_file_show("."))
    yield _show_case("points-file-too-big", points_file_show("big.csv", _big_csv))
    yield _show_case("points-file-too-many-points", points_file_show("many.csv", _many_points_csv))
    yield _show_case("points-file-nul", points_file_show("nul.csv", _nul_csv))
    yield _show_case("points-file-not-utf8", points_file_show("latin1.csv", _latin1_csv))
    yield _show_case("points-file-nul-in-name", points_file_show("a\u0000b.csv"))
    yield _show_case("drones-int64-max", _drones(9223372036854775807))
    yield _show_case("drones-int64-max-sim", _drones(9223372036854775807), "sim")
    yield _show_case("drones-zero", _drones(0))
    yield _show_case("drones-100000", _drones(100_000).replace("size = 9.0", "size = 500000.0")
                     .replace("spacing = 3.0\ncolumns = 2", "spacing = 3.0"))
    yield _show_case("drones-huge-int", _drones(10**40))
    yield _show_case("random-20000-in-10m", random_layout_show(20_000, 10.0))
    yield _show_case("random-1000-in-10m", random_layout_show(1000, 10.0))
    yield _show_case("size-1e308", show_with(size="size = 1e308"))
    yield _show_case("size-huge-int", show_with(size=f"size = {10**400}"))
    yield _show_case("transition-1e9", show_with(transition="transition = 1e9"))
    yield _show_case("hold-1e12", show_with(hold="hold = 1e12"))
    yield _show_case("count-1e9", show_with(formation__count="count = 1000000000"))
    yield _show_case("dt-1e-9", show_with(planner__dt="dt = 1e-9"))
    yield _show_case("steps-1e9", show_with(planner__steps="steps = 1000000000"))
    yield _show_case("steps-per-transition", show_with(transition="transition = 500.0"))
    yield _show_case("max-iterations-1e9", show_with(
        planner__max_iterations="max_iterations = 1000000000"))
    yield _show_case("alpha-1e300", show_with(planner__alpha="alpha = 1e300"))
    yield _show_case("nested-arrays-5000", "a = " + "[" * 5000 + "]" * 5000 + "\n")
    yield _show_case("dotted-key-100000", show_with(
        show__deep="deep." + ".".join(["a"] * 100_000) + " = 1"))
    yield _show_case("table-name-100000", "[" + ".".join(["a"] * 100_000) + "]\n")
    yield _show_case("nested-tables-5000", "a = " + "{a=" * 5000 + "1" + "}" * 5000 + "\n")
    yield _show_case("nested-center-900", show_with(
        center="center = " + "[" * 900 + "]" * 900))
    yield _show_case("nested-center-300", show_with(
        center="center = " + "[" * 300 + "]" * 300))
    yield _show_case("heading-1e300", show_with(origin__heading="heading = 1e300"))
    yield _show_case("heading-1e300-sim", show_with(origin__heading="heading = 1e300"), "sim")
    yield _show_case("alt-minus-1e30", show_with(alt="alt = -1e30"))
    yield _show_case("alt-minus-1e30-check", show_with(alt="alt = -1e30"), "check-show")
    yield _show_case("rotation-1e300", show_with(formation__rotation="rotation = 1e300"))
    yield _show_case("center-1e300", show_with(center="center = [1e300, 0.0, 10.0]"))
    yield _show_case("arms-1e9", show_with(shape='shape = "star"',
                                           formation__arms="arms = 1000000000"))
    yield _show_case("turns-1e9", show_with(shape='shape = "spiral"',
                                            formation__turns="turns = 1e9"))
    yield _show_case("text-100000", show_with(shape='shape = "text"',
                                              size='text = "' + "A" * 100_000 + '"'))
    yield _show_case("grid-rows-columns-huge", show_with(
        shape='shape = "grid"', size="rows = 100000", formation__columns="columns = 100000",
        formation__spacing="spacing = 2.0"))
    yield _show_case("takeoff-columns-huge", show_with(columns="columns = 1000000000000000000",
                                                       spacing="spacing = 1000.0"))
    yield _show_case("takeoff-spacing-1e300", show_with(spacing="spacing = 1e300"))
    yield _show_case("random-seed-negative", random_layout_show(4, 100.0).replace(
        'layout = "random"', 'layout = "random"\nseed = -1'))
    yield _show_case("random-area-1e300", random_layout_show(4, 1e300))
    yield _show_case("geofence-2000-corners", show_with(limits__geofence="geofence = [" + ", ".join(
        f"[{i}, {i % 7}]" for i in range(2000)) + "]"))
    yield _show_case("max-speed-1e300", show_with(limits__max_speed_h="max_speed_h = 1e300"))
    yield _show_case("min-separation-1e300", show_with(
        min_separation="min_separation = 1e300"))
    yield _show_case("flight-time-over-battery", long_show(12, 80.0))
    yield _show_case("max-flight-time-1e9", show_with(
        limits__max_flight_time="max_flight_time = 1e9"))
    yield _show_case("name-newline-escape", show_with(name='name = "a\\nb\\u001b[31m"'))
    yield _show_case("formation-name-newline", BASE_SHOW.replace(
        'name = "line"', 'name = "ring\\nsecond line"'))
    yield _show_case("key-with-newline", show_with(show__quoted='"a\\nb" = 1'))
    yield _show_case("colors-5000", show_with(formation__colors="colors = [" + ", ".join(
        ['"#ffffff"'] * 5000) + "]").replace('color = "#ff0000"\n', ""))
    yield _show_case("inline-points-100000", show_with(
        shape='shape = "points"', size="points = [" + ",".join(["[0,0,10]"] * 100_000) + "]",
        center="center = [0.0, 0.0, 0.0]"))
    yield _show_case("drones-as-date", show_with(drones="drones = 1979-05-27"))
    yield Case("show-file-dev-zero", lambda d: _command("plan", _symlink_to(
        "/dev/zero", "zero.toml")(d)))
    yield Case("show-file-fifo", lambda d: _command("plan", _fifo_toml(d)))
    yield Case("show-file-directory", lambda d: _command("plan", _dir("dir.toml")(d)))
    yield Case("show-file-too-big", lambda d: _command("plan", _bytes(
        "big.toml", b"# " + b"x" * (3 << 20) + b"\n")(d)))
    yield Case("show-file-empty", lambda d: _command("plan", _bytes("empty.toml", b"")(d)))
    yield Case("show-file-binary", lambda d: _command("plan", _bytes(
        "bin.toml", os.urandom(4096))(d)))


def _fifo_toml(d: Path) -> Path:
    path = d / "pipe.toml"
    os.mkfifo(path)
    return path


def _skyc_case(name: str, members: Callable[[zipfile.ZipFile], None],
               command: str = "plan", suffix: str = ".skyc") -> Case:
    def make(d: Path) -> Argv:
        path = d / f"{name}{suffix}"
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
            members(zf)
        if command == "dry-run":
            return ["dry-run", str(path), "--no-record", "-q", "--no-console"]
        return [command, str(path)]
    return Case(name, make)


def _zeros(name: str, size: int) -> Callable[[zipfile.ZipFile], None]:
    def write(zf: zipfile.ZipFile) -> None:
        chunk = bytes(1 << 20)
        with zf.open(name, "w", force_zip64=True) as f:
            for _ in range(size >> 20):
                f.write(chunk)
    return write


def _doc(text: str, name: str = "show.json") -> Callable[[zipfile.ZipFile], None]:
    def write(zf: zipfile.ZipFile) -> None:
        zf.writestr(name, text)
    return write


def _skyc_drone(points: str = "[[0, [0, 0, 0], []], [3, [0, 0, 5], []]]") -> str:
    return ('{"type": "generic", "settings": {"trajectory": {"version": 1, "points": '
            + points + '}}}')


def skyc_cases() -> Iterator[Case]:
    """Skybrush .skyc archives: zip bombs, names leaving the archive, too many drones."""
    yield _skyc_case("skyc-bomb-512mib", _zeros("show.json", 512 << 20))
    yield _skyc_case("skyc-bomb-512mib-dry-run", _zeros("show.json", 512 << 20), "dry-run")
    yield _skyc_case("skyc-traversal", _doc("{}", "../../../etc/show.json"))
    yield _skyc_case("skyc-absolute-name", _doc("{}", "/etc/show.json"))
    yield _skyc_case("skyc-no-show-json", _doc("{}", "other.json"))
    yield _skyc_case("skyc-deep-json", _doc("[" * 200_000 + "]" * 200_000))
    yield _skyc_case("skyc-10001-drones", _doc('{"version": 1, "swarm": {"drones": ['
                                               + ", ".join([_skyc_drone()] * 10_001) + "]}}"))
    yield _skyc_case("skyc-nan-point", _doc('{"version": 1, "swarm": {"drones": ['
                                            + _skyc_drone("[[0, [0, 0, 0], []], [3, [NaN, 0,"
                                                          " 5], []]]") + "]}}"))
    yield _skyc_case("skyc-huge-number", _doc('{"version": 1, "swarm": {"drones": ['
                                              + _skyc_drone("[[0, [0, 0, 0], []], [1e999, "
                                                            "[0, 0, 5], []]]") + "]}}"))
    yield _skyc_case("skyc-bad-base64", _doc(
        '{"version": 1, "swarm": {"drones": [{"settings": {"trajectory": {"version": 1, '
        '"points": [[0, [0, 0, 0], []], [3, [0, 0, 5], []]]}, "lights": {"version": 1, '
        '"data": "***"}}}]}}'))
    yield _skyc_case("skyc-endless-light-loop", _doc(
        '{"version": 1, "swarm": {"drones": [{"settings": {"trajectory": {"version": 1, '
        '"points": [[0, [0, 0, 0], []], [3, [0, 0, 5], []]]}, "lights": {"version": 1, '
        '"data": "EgA="}}}]}}'))
    yield _skyc_case("skyc-not-a-show-check", _doc("{}"), "check")
    yield _skyc_case("csv-zip-bomb-512mib", _zeros("Drone 1.csv", 512 << 20), suffix=".zip")
    yield _skyc_case("csv-zip-traversal", _doc("0,0,0,0,0,0,0\n", "../Drone 1.csv"),
                     suffix=".zip")
    yield _skyc_case("csv-zip-not-numbers", _doc("0,0,0,0,0,0,0\n1,a,b,c,d,e,f\n",
                                                 "Drone 1.csv"), suffix=".zip")


def corpus() -> list[Case]:
    """Every hostile case, plan files first."""
    return [*plan_cases(), *show_cases(), *skyc_cases()]


@dataclass
class Tally:
    """The corpus figures: cases, crashes, tracebacks, one-line refusals."""

    cases: int = 0
    crashes: int = 0
    tracebacks: int = 0
    refusals: int = 0
    failures: list[str] = field(default_factory=list)

    def add(self, case: Case, outcome: Outcome) -> None:
        self.cases += 1
        self.crashes += outcome.crashed
        self.tracebacks += outcome.traceback
        if outcome.one_line_refusal(case.forbidden):
            self.refusals += 1
        else:
            self.failures.append(case.name)


def prepare(case: Case, root: Path) -> tuple[Path, Argv]:
    """A fresh directory for ``case`` under ``root`` and the argv its files need."""
    directory = root / case.name
    directory.mkdir(parents=True)
    argv = case.make(directory)
    return directory, argv

