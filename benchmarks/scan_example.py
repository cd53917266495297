"""What `pimbs scan` prints for the README's own-board walkthrough, on the simulated boards.

Runs the two scans the README quotes (the lab board's profile behind the emulated SLCAN
adapter, and the ODrive robot on the virtual bus) and prints their lines; frame counts and
bus load are measured, so they vary a little from run to run and with the machine's load.

    .venv/bin/python benchmarks/scan_example.py            # the scans' own output
    .venv/bin/python benchmarks/scan_example.py --readme   # the README's block
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README_BLOCK = True
LAB = "fixtures/lab-board/two-link-lab.muscles.yaml"
ODRIVE = "fixtures/lab-board/two-link-odrive.muscles.yaml"


def scan(port: str, robot: str, python: str = sys.executable) -> list[str]:
    """The report of `pimbs scan --port PORT --robot ROBOT` run from the root."""
    run = subprocess.run([python, "-m", "pimbs_cli.main", "scan", "--port", port, "--robot",
                          robot], cwd=ROOT, capture_output=True, text=True, check=False)
    if run.returncode != 0:
        raise SystemExit(f"pimbs scan --port {port} --robot {robot} failed "
                         f"(exit {run.returncode}): {run.stderr.strip()[-400:]}")
    lines = run.stdout.rstrip("\n").splitlines()
    start = next((k for k, line in enumerate(lines) if line.startswith("port ")), None)
    if start is None:
        raise SystemExit(f"pimbs scan --port {port}: no summary line in {lines!r}")
    return lines[start:]  # from its summary on (a line before it says a mock was started)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--readme", action="store_true", help="print the README block")
    args = ap.parse_args()
    lab, odrive = scan("slcan-pty", LAB), scan("virtual", ODRIVE)
    if not args.readme:
        print("\n".join(lab + [""] + odrive))
        return 0
    load = re.search(r"bus load ([\d.]+ %)", odrive[0])
    boards = re.search(r"(\d+) board\(s\)", odrive[0])
    firmware = sorted({line.split()[3] for line in odrive[2:]})
    print("Against the simulated boards of that profile, through python-can's real `slcan` "
          "interface:\n"
          f"`pimbs scan --port slcan-pty --robot {LAB}` printed\n"
          "(`.venv/bin/python benchmarks/scan_example.py`)\n\n"
          "```\n" + "\n".join(lab[:3]) + "\n```\n\n"
          f"(one line per board; the ODrive robot `{ODRIVE}` on\n"
          f"`--port virtual`: firmware `{', '.join(firmware)}`, {load[1] if load else '?'} bus "
          f"load while only listening, {boards[1] if boards else '?'} boards).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
