"""Collection throughput on the mock bus: settle detection vs fixed waits, same poses.

    .venv/bin/python benchmarks/bench_collect.py [--samples 15] [--speed 1] [--waits 0.25 0.5 1]

Runs the real routine (ramps, settling, crash-safe writes) against the simulated boards on a
python-can virtual bus, once with settle detection and once per fixed wait (in place of the
detection before the reading; the rest of the routine is the same), and prints samples/min
next to two data-quality numbers, because a fixed wait is only faster by being too short:
the RMS torque-balance residual |−Gᵀf − τ| (N·m; sensor noise alone gives about 0.005) and
the worst |θ − θ_command| (rad). ``--speed`` is the mock's time speed-up (1 = real time; the
dynamics settle with a 75 ms time constant plus a 10-60 ms solver latency per new command).
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
from pimbs_hw.collection.move import MoveConfig  # noqa: E402
from pimbs_hw.collection.plan import CollectionPlan  # noqa: E402
from pimbs_hw.collection.resume import collection_meta, open_recording  # noqa: E402
from pimbs_hw.collection.routine import Collector  # noqa: E402
from pimbs_hw.collection.session import open_link  # noqa: E402
from pimbs_hw.collection.settle import SettleConfig  # noqa: E402
from pimbs_recording.format import read_recording  # noqa: E402


def run(model: ArmModel, samples: int, speed: float, settle: SettleConfig, out: Path
        ) -> tuple[float, float, float]:
    """(samples/min, RMS balance residual N·m, max |θ − θ_cmd| rad) of one collection."""
    plan = CollectionPlan(model, samples, seed=11)
    moves = MoveConfig(speed=speed)
    meta = collection_meta(model, plan.meta(), port="virtual", simulated=True,
                           settle=settle.meta(), move=moves.meta())
    writer, start = open_recording(out, meta, resume=False)
    with open_link("virtual", model.robot, seed=11, speed=speed) as link:
        collector = Collector(link, model, plan, writer, start, settle, move=moves)
        t0 = time.monotonic()
        collector.run()
        elapsed = time.monotonic() - t0
    rec = read_recording(out)
    G = model.muscle_jacobian(rec.theta)
    residual = -np.einsum("bmn,bm->bn", G, rec.tension) - rec.tau_gravity
    return (60.0 * samples / elapsed, float(np.sqrt(np.mean(residual ** 2))),
            float(np.abs(rec.theta - rec.theta_command).max()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=15)
    parser.add_argument("--speed", type=float, default=1.0)
    parser.add_argument("--waits", type=float, nargs="+", default=[0.25, 0.5, 1.0],
                        help="fixed waits before each reading, s (at speed 1; divided by --speed)")
    args = parser.parse_args()
    model = ArmModel.load("two-link-4-muscle")
    configs = [("settle detection", SettleConfig())] + [
        (f"fixed wait {w:g} s", SettleConfig(fixed_wait=w / args.speed)) for w in args.waits]
    print(f"two-link-4-muscle, {args.samples} samples, mock speed {args.speed:g}x")
    print(f"{'':<22}{'samples/min':>12}{'RMS resid N·m':>15}{'max |θ-θcmd| rad':>18}")
    with tempfile.TemporaryDirectory() as tmp:
        for k, (name, settle) in enumerate(configs):
            rate, resid, dtheta = run(model, args.samples, args.speed, settle,
                                      Path(tmp) / f"run{k}.parquet")
            print(f"{name:<22}{rate:>12.1f}{resid:>15.4f}{dtheta:>18.4f}", flush=True)


if __name__ == "__main__":
    main()
