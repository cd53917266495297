"""The paper's Tables I–III as the README quotes them: `pimbs experiment`, then its tables.

Runs ``pimbs experiment`` with the given epochs, seeds and tables into ``--out`` and prints
the Markdown tables it wrote (``tables.md``). The README's tables were made with
``--epochs 2000 --seeds 5`` (all three tables) and ``--tables 1 --n-train 5 --epochs 20000``
(the column rerun at the paper's length): hours of CPU, so run it on a quiet machine.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/paper_tables.py --epochs 2000 --seeds 5
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epochs", type=int, default=2000)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--tables", default="1,2,3")
    ap.add_argument("--n-train", type=int, action="append", default=[])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", type=Path, default=Path("paper-tables"))
    args = ap.parse_args()
    pimbs = str(Path(sys.executable).with_name("pimbs"))
    cmd = [pimbs, "experiment", "--epochs", str(args.epochs), "--seeds", str(args.seeds),
           "--tables", args.tables, "--threads", str(args.threads), "--out", str(args.out),
           "--force", *(a for n in args.n_train for a in ("--n-train", str(n)))]
    run = subprocess.run(cmd, check=False)
    if run.returncode != 0:
        print(f"{' '.join(cmd)} failed (exit {run.returncode})", file=sys.stderr)
        return run.returncode
    print((args.out / "tables.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
