"""Run the whole test suite N times in a row while another CPU-bound process runs.

What "never flakes" means here: on a 2-core machine, with one extra process spinning
on a core the whole time, the README's test command passes every time. Prints one line per
run and a closing "N passed, N failed" line; exits non-zero if any run failed.

    .venv/bin/python benchmarks/suite_under_load.py --runs 10
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
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--hogs", type=int, default=1, help="CPU-bound processes beside the suite")
    ap.add_argument("--workers", default="2", help="pytest -n (as the README's command)")
    args = ap.parse_args()
    hogs = [mp.Process(target=_spin, daemon=True) for _ in range(args.hogs)]
    for h in hogs:
        h.start()
    passed = failed = 0
    try:
        for k in range(1, args.runs + 1):
            t0 = time.monotonic()
            r = subprocess.run([sys.executable, "-m", "pytest", "-n", args.workers, "-q", "-p",
                                "no:cacheprovider"], cwd=ROOT, capture_output=True, text=True)
            tail = (r.stdout.strip().splitlines() or ["(no output)"])[-1]
            ok = r.returncode == 0
            passed, failed = passed + ok, failed + (not ok)
            print(f"run {k}/{args.runs}: {'ok' if ok else 'FAILED'} in "
                  f"{time.monotonic() - t0:.0f} s: {tail}", flush=True)
            if not ok:
                print(r.stdout[-4000:], flush=True)
    finally:
        for h in hogs:
            h.terminate()
    print(f"{passed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
