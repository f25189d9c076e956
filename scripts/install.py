"""Install groundctl and its test extras into the running interpreter's venv, quickly.

``./scripts/test`` runs this with ``.venv/bin/python``.  pip takes about a minute on a
fresh venv here (26 s resolving and fetching, 22 s byte-compiling, the rest unpacking):
an eighth of CI's eight minutes.  uv installs the same packages, byte-compiled, in
about 15 s.  So: install uv into the venv with pip, then let uv install the rest,
resolving exactly as pip would -- the same configuration (pip's own: its config files
and ``PIP_*`` variables, read through ``pip config list``) and the same choice among
several indexes (the best version on any of them, pip's rule; uv's default is the
first index that has the package), and nothing of uv's own configuration (no
``uv.toml``, no ``UV_*`` variable but the cache's).  Wherever that cannot be done
faithfully -- a pip
setting this does not translate, no uv to be had (no network to the registry), uv
failing -- pip installs as before, after one line saying why.

No third-party imports: this runs before anything is installed.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from dataclasses import dataclass, field

#: What the suite needs (pyproject.toml's extras).
TARGET = "-e", ".[test,ray]"

#: pip settings that change nothing uv needs to know.
IGNORED = frozenset({
    "disable-pip-version-check", "progress-bar", "no-cache-dir", "cache-dir", "quiet",
    "verbose", "no-color", "root-user-action", "no-warn-script-location",
    "break-system-packages", "no-input", "retries", "log",
})

#: Sections of pip's configuration that apply to ``pip install``, weakest first.
SECTIONS = ("global", "install", ":env:")
#: Names pip takes as one setting.
ALIASES = {"default-timeout": "timeout"}
#: pip's true values (its ``strtobool``).
TRUE = frozenset({"y", "yes", "t", "true", "on", "1"})
#: uv, pinned to the release whose options (and whose recompiling nothing on an install
#: that changes nothing) this was written against; a venv's older uv is replaced.
UV = "uv>=0.13,<0.14"


class Untranslatable(Exception):
    """A pip setting that uv cannot be told to honour the same way."""


@dataclass
class UvCall:
    """uv's options and environment equivalent to a pip configuration."""

    args: list[str] = field(default_factory=list)
    env: dict[str, str] = field(default_factory=dict)


def pip_settings(listing: str) -> dict[str, str]:
    """``pip config list`` output (``section.key='value'`` per line) as the settings
    ``pip install`` would use: ``[install]`` over ``[global]``, ``PIP_*`` variables
    over both; sections for other pip commands dropped, aliases as one setting, empty
    values (which pip ignores) dropped."""
    ranked: dict[str, tuple[int, str]] = {}
    for line in listing.splitlines():
        name, sep, raw = line.partition("=")
        section, dot, key = name.rpartition(".")
        if not (sep and dot) or section not in SECTIONS:
            continue
        value = str(ast.literal_eval(raw))
        if not value:
            continue
        key = ALIASES.get(key, key)
        rank = SECTIONS.index(section)
        if key not in ranked or ranked[key][0] <= rank:
            ranked[key] = rank, value
    return {key: value for key, (_, value) in ranked.items()}


def uv_call(settings: dict[str, str]) -> UvCall:
    """The uv options that make ``uv pip install`` resolve what pip would; raises
    :class:`Untranslatable` naming the first setting it cannot carry over."""
    call = UvCall(args=["--no-config", "--index-strategy", "unsafe-best-match"])
    for key, value in settings.items():
        words = value.split()
        if key in IGNORED:
            continue
        if key == "index-url":
            call.args += ["--index-url", value]
        elif key in ("extra-index-url", "find-links", "constraint", "trusted-host"):
            flag = {"extra-index-url": "--extra-index-url", "find-links": "--find-links",
                    "constraint": "--constraint",
                    "trusted-host": "--allow-insecure-host"}[key]
            for word in words:
                call.args += [flag, word]
        elif key == "no-index":
            if value.lower() in TRUE:
                call.args.append("--no-index")
        elif key == "cert":
            call.env["SSL_CERT_FILE"] = value
        elif key == "timeout":
            call.env["UV_HTTP_TIMEOUT"] = str(max(1, round(float(value))))
        else:
            raise Untranslatable(key)
    return call


def run(*cmd: str, env: dict[str, str] | None = None) -> bool:
    return subprocess.run(cmd, env=env).returncode == 0


def main() -> int:
    py = sys.executable
    pip = [py, "-m", "pip", "install", "-q", "--disable-pip-version-check"]
    why = ""
    try:
        listing = subprocess.run([py, "-m", "pip", "config", "list"], check=True,
                                 capture_output=True, text=True).stdout
        call = uv_call(pip_settings(listing))
    except Untranslatable as e:
        why = f"pip's setting {e.args[0]!r} has no uv equivalent here"
    except (subprocess.CalledProcessError, SyntaxError, ValueError) as e:
        why = f"pip's configuration could not be read ({e})"
    uv = os.path.join(os.path.dirname(py), "uv")
    if not why and not run(*pip, UV):  # nothing to do once it is there
        why = "uv could not be installed"
    if not why:
        # uv's own variables would change what it resolves: only its cache is kept.
        env = {k: v for k, v in os.environ.items()
               if not k.startswith("UV_") or k == "UV_CACHE_DIR"}
        env.update(call.env)
        if run(uv, "pip", "install", "-q", "--python", py, "--compile-bytecode",
               *call.args, *TARGET, env=env):
            return 0
        why = "uv failed"
    print(f"scripts/install.py: {why}; installing with pip", file=sys.stderr)
    return 0 if run(*pip, *TARGET) else 1


if __name__ == "__main__":
    sys.exit(main())
