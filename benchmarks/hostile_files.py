"""Run the hostile-file corpus through the real CLI and count what happened.

    .venv/bin/python benchmarks/hostile_files.py [--only SUBSTRING ...] [--skip SUBSTRING ...]
        [--timeout S] [--verbose]

Prints ``cases``, ``crashes`` (killed by a signal or at the deadline),
``tracebacks`` and ``one-line refusals / total`` (non-zero exit, no traceback,
exactly one line on stderr, no file contents echoed).  The corpus itself is
``sitl_tests/hostile_corpus.py``; each case runs in a forked child with its
address space capped at 2 GiB above this process's and a deadline.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "sitl_tests"))

from hostile_corpus import Tally, corpus, prepare, run_case


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="*", default=[], help="run cases whose name has one of these")
    p.add_argument("--skip", nargs="*", default=[], help="skip cases whose name has one of these")
    p.add_argument("--timeout", type=float, default=30.0, help="deadline per case, s")
    p.add_argument("--verbose", action="store_true", help="one line per case")
    args = p.parse_args()
    cases = [c for c in corpus()
             if (not args.only or any(s in c.name for s in args.only))
             and not any(s in c.name for s in args.skip)]
    tally = Tally()
    with tempfile.TemporaryDirectory(prefix="groundctl-hostile-") as tmp:
        for case in cases:
            directory, argv = prepare(case, Path(tmp))
            out = run_case(argv, directory, timeout=args.timeout)
            tally.add(case, out)
            if args.verbose:
                verdict = ("crash" if out.crashed else "traceback" if out.traceback else
                           "ok" if out.one_line_refusal(case.forbidden) else
                           f"{len(out.lines)} lines, exit {out.exit_code}")
                last = out.lines[-1][:150] if out.lines else ""
                print(f"{case.name:42s} {verdict:18s} {out.seconds:5.2f} s  {last}",
                      flush=True)
    print(f"cases: {tally.cases}")
    print(f"crashes: {tally.crashes}")
    print(f"tracebacks: {tally.tracebacks}")
    print(f"one-line refusals: {tally.refusals} / {tally.cases}")
    if tally.failures:
        print(f"not refused in one line: {', '.join(tally.failures)}")
    return 0 if tally.refusals == tally.cases else 1


if __name__ == "__main__":
    sys.exit(main())
