"""`pimbs import` speed on a long log: write an hour of a synthetic ROS log, time the import.

    .venv/bin/python benchmarks/bench_import.py [--minutes 60] [--format ros1|sqlite3|mcap]
        [--robot left-arm-5dof]

The log is what ``rosbag record`` of a tendon-driven arm holds (``pimbs_import.synthetic``):
/joint_states at 200 Hz (with joints the robot does not drive), /muscle_states at 100 Hz,
/muscle_temperature at 10 Hz, the arm ramping 2 s between poses it holds 8 s, with sensor
noise and receive jitter. Prints the message count, the import's wall time (reading,
alignment, held-pose detection, writing the recording) and whether every held pose became
exactly one row. Writing the log is not timed. Wall time on a shared machine depends on the
load; the CPU time of the importing process is printed next to it.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pimbs_arm.model import ArmModel  # noqa: E402
from pimbs_import.convert import import_log  # noqa: E402
from pimbs_import.mapping import DEFAULT  # noqa: E402
from pimbs_import.synthetic import LogSpec, write_log  # noqa: E402
from pimbs_recording.format import read_recording, write_recording  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--format", default="ros1", choices=["ros1", "sqlite3", "mcap"])
    parser.add_argument("--robot", default="left-arm-5dof")
    args = parser.parse_args()
    arm = ArmModel.load(args.robot)
    hold, ramp = 8.0, 2.0
    poses = int(args.minutes * 60 / (hold + ramp))
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / ("log.bag" if args.format == "ros1" else "log")
        t0 = time.perf_counter()
        truth = write_log(log, arm, LogSpec(poses=poses, hold_s=hold, ramp_s=ramp),
                          args.format)
        written = time.perf_counter() - t0
        counted = []

        def progress(done: int, total: int) -> None:
            counted[:] = [total]

        t0, c0 = time.perf_counter(), time.process_time()
        data, meta = import_log(log, arm, DEFAULT, progress)
        write_recording(Path(tmp) / "out.parquet", data, meta)
        took, cpu = time.perf_counter() - t0, time.process_time() - c0
        rec = read_recording(Path(tmp) / "out.parquet")
        err = np.abs(rec.theta - truth.theta).max() if rec.n_rows == poses else float("nan")
    print(f"{args.format} log of {meta['log_span_s'] / 60:.1f} min, {args.robot}: "
          f"{counted[0]} messages (written in {written:.0f} s)")
    print(f"import: {took:.1f} s wall, {cpu:.1f} s CPU ({counted[0] / took:,.0f} messages/s "
          f"wall); "
          f"{rec.n_rows} rows for {poses} held poses; max |theta - truth| {err:.2g} rad")


if __name__ == "__main__":
    main()
