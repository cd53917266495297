"""Run the whole test suite N times in a row while other CPU-bound processes run.

What "never flakes" means here: on a 2-core machine, with two extra processes spinning the
whole time (one per core), the README's test command passes every time. Prints one line per
run and a closing "N passed, N failed" line; exits non-zero if any run failed.

    .venv/bin/python benchmarks/suite_under_load.py --runs 5
    .venv/bin/python benchmarks/suite_under_load.py --runs 5 --readme   # and the README block
    .venv/bin/python benchmarks/suite_under_load.py --runs 3 tests/test_collect.py
                                          # only these tests (a change's own check)
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _spin() -> None:
    while True:
        pass


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--hogs", type=int, default=2, help="CPU-bound processes beside the suite")
    ap.add_argument("--workers", default="2", help="pytest -n (as the README's command)")
    ap.add_argument("--readme", action="store_true",
                    help="print the README block at the end (the whole suite only)")
    ap.add_argument("tests", nargs="*", help="test files or ids to run (default: the suite)")
    args = ap.parse_args()
    if args.readme and args.tests:
        ap.error("--readme measures the whole suite: give no test files")
    hogs = [mp.Process(target=_spin, daemon=True) for _ in range(args.hogs)]
    for h in hogs:
        h.start()
    passed = failed = 0
    seconds = []
    try:
        for k in range(1, args.runs + 1):
            t0 = time.monotonic()
            r = subprocess.run([sys.executable, "-m", "pytest", "-n", args.workers, "-q", "-p",
                                "no:cacheprovider", *args.tests], cwd=ROOT, capture_output=True,
                               text=True)
            seconds.append(time.monotonic() - t0)
            tail = (r.stdout.strip().splitlines() or ["(no output)"])[-1]
            ok = r.returncode == 0
            passed, failed = passed + ok, failed + (not ok)
            print(f"run {k}/{args.runs}: {'ok' if ok else 'FAILED'} in "
                  f"{seconds[-1]:.0f} s: {tail}", flush=True)
            if not ok:
                print(r.stdout[-4000:], flush=True)
    finally:
        for h in hogs:
            h.terminate()
    print(f"{passed} passed, {failed} failed")
    if args.readme:
        spinning = {0: "alone", 1: "while one extra process spins on a core"}.get(
            args.hogs, f"while {args.hogs} extra processes spin")
        print(f"**The suite under load** (`.venv/bin/python benchmarks/suite_under_load.py "
              f"--runs {args.runs} --hogs {args.hogs}`: the\nwhole suite, `pytest -n "
              f"{args.workers}`, {args.runs} times in a row {spinning}):\n{passed} passed, "
              f"{failed} failed, {min(seconds):.0f}–{max(seconds):.0f} s per run. No test "
              "depends on wall-clock speed: the\nsimulated boards run on a clock that stands "
              "still while the test process cannot run, and\nthe simulated arm moves only "
              "toward the equilibrium of the commands in force, whatever its\nsolver's wall "
              "time (`tests/test_host_starvation.py`, `tests/test_load_robustness.py`).")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
