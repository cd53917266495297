"""How long `pimbs --help` takes to start, and how long importing its entry point takes.

Commands are registered lazily, so `--help` must not import torch, pinocchio or pyarrow;
this measures it in fresh processes (median of ``--repeats`` runs, wall time).

    .venv/bin/python benchmarks/cli_startup.py            # one line
    .venv/bin/python benchmarks/cli_startup.py --readme   # the README's block
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README_BLOCK = True
HEAVY = ("torch", "pinocchio", "pyarrow", "matplotlib")


def _wall(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True)
    return time.perf_counter() - t0


def measure(repeats: int, python: str = sys.executable) -> dict[str, object]:
    """Median wall seconds of `pimbs --help` and of importing the entry point, and which
    heavy packages that import pulls in."""
    pimbs = str(Path(python).with_name("pimbs"))
    help_s = statistics.median(_wall([pimbs, "--help"]) for _ in range(repeats))
    import_s = statistics.median(_wall([python, "-c", "import pimbs_cli.main"])
                                 for _ in range(repeats))
    probe = ("import sys, pimbs_cli.main; "
             f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))")
    loaded = subprocess.run([python, "-c", probe], cwd=ROOT, check=True, capture_output=True,
                            text=True).stdout.split()
    return {"help_s": help_s, "import_s": import_s, "heavy": loaded}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--readme", action="store_true", help="print the README block")
    args = ap.parse_args()
    m = measure(args.repeats)
    heavy = ", ".join(m["heavy"]) or "none of " + ", ".join(HEAVY)
    if args.readme:
        print(f"`pimbs --help` starts in **{m['help_s']:.2f} s** and importing its entry point "
              f"takes {m['import_s']:.2f} s (median of {args.repeats} fresh processes, wall "
              f"time, `.venv/bin/python benchmarks/cli_startup.py`); that import loads "
              f"{heavy}.")
    else:
        print(f"pimbs --help {m['help_s']:.3f} s, import {m['import_s']:.3f} s, heavy: {heavy}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
