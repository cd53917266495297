"""How many tests the suite has, as pytest collects them (no test is run).

    .venv/bin/python benchmarks/test_count.py            # one line
    .venv/bin/python benchmarks/test_count.py --readme   # the README's block
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README_BLOCK = True


def count_tests(python: str = sys.executable) -> tuple[int, int]:
    """(tests, test files) that ``pytest --collect-only -q`` lists."""
    run = subprocess.run([python, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider"],
                         cwd=ROOT, capture_output=True, text=True, check=False)
    ids = [line for line in run.stdout.splitlines() if "::" in line]
    if run.returncode != 0 or not ids:
        raise SystemExit(f"pytest --collect-only failed (exit {run.returncode}): "
                         f"{(run.stdout + run.stderr).strip()[-400:]}")
    files = {line.split("::")[0] for line in ids}
    summary = re.search(r"(\d+) tests? collected", run.stdout)
    if summary and int(summary[1]) != len(ids):
        raise SystemExit(f"pytest says {summary[1]} tests but lists {len(ids)}")
    return len(ids), len(files)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--readme", action="store_true", help="print the README block")
    args = ap.parse_args()
    tests, files = count_tests()
    if args.readme:
        print(f"The suite has **{tests} tests** in {files} files "
              "(`.venv/bin/python benchmarks/test_count.py`: what `pytest --collect-only -q` "
              "lists).")
    else:
        print(f"{tests} tests in {files} files")
    return 0


if __name__ == "__main__":
    sys.exit(main())
