"""Collection throughput on the mock bus: settle detection vs fixed waits, same poses.

    .venv/bin/python benchmarks/bench_collect.py [--samples 15] [--speed 1] [--waits 0.25 0.5 1]
    .venv/bin/python benchmarks/bench_collect.py --samples 40 --seed 2 --waits  # the main job

Runs the real routine (ramps, settling, crash-safe writes) against the simulated boards on a
python-can virtual bus, once with settle detection and once per fixed wait (in place of the
detection before the reading; the rest of the routine is the same), and prints samples/min
next to two data-quality numbers, because a fixed wait is only faster by being too short:
the RMS torque-balance residual |−Gᵀf − τ| (N·m; sensor noise alone gives about 0.005) and
the worst |θ − θ_command| (rad). ``--speed`` is the mock's time speed-up (1 = real time; the
dynamics settle with a 75 ms time constant plus a 10-60 ms solver latency per new command).
The built-in quasi-static arm says when it is at rest (its equilibrium solved), so the rest
before each move costs it nothing in either mode; the fixed wait replaces the settle detection
before each reading only.
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


class AsIfDynamic:
    """The simulated arm's link, with what the quasi-static arm says about itself hidden:
    the routine then waits for rest and loads held wires as for an arm with inertia."""

    quasi_static = False

    def __init__(self, link) -> None:
        self.link = link

    def __getattr__(self, name: str):
        return getattr(self.link, name)

    def at_rest(self) -> None:
        return None


def run(model: ArmModel, samples: int, speed: float, settle: SettleConfig, out: Path,
        seed: int = 11, dynamic: bool = False) -> tuple[float, float, float, float]:
    """(samples/min, RMS balance residual N·m, max |θ − θ_cmd| rad, wall s) of one
    collection (``dynamic``: as for an arm with inertia, ``AsIfDynamic``)."""
    plan = CollectionPlan(model, samples, seed=seed)
    moves = MoveConfig(speed=speed)
    meta = collection_meta(model, plan.meta(), port="virtual", simulated=True,
                           settle=settle.meta(), move=moves.meta())
    writer, start = open_recording(out, meta, resume=False)
    with open_link("virtual", model.robot, seed=seed, speed=speed) as link:
        collector = Collector(AsIfDynamic(link) if dynamic else link, model, plan, writer,
                              start, settle, move=moves)
        t0 = time.monotonic()
        collector.run()
        elapsed = time.monotonic() - t0
    rec = read_recording(out)
    G = model.muscle_jacobian(rec.theta)
    residual = -np.einsum("bmn,bm->bn", G, rec.tension) - rec.tau_gravity
    return (60.0 * rec.n_rows / elapsed, float(np.sqrt(np.mean(residual ** 2))),
            float(np.abs(rec.theta - rec.theta_command).max()), elapsed)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=15)
    parser.add_argument("--speed", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--dynamic", action="store_true",
                        help="also run settle detection as for an arm with inertia (rest "
                             "before each move, held wires loaded at the tension rate)")
    parser.add_argument("--waits", type=float, nargs="*", default=[0.25, 0.5, 1.0],
                        help="fixed waits before each reading, s (at speed 1; divided by --speed)")
    args = parser.parse_args()
    model = ArmModel.load("two-link-4-muscle")
    configs = [("settle detection", SettleConfig(), False)] + (
        [("as if dynamic", SettleConfig(), True)] if args.dynamic else []) + [
        (f"fixed wait {w:g} s", SettleConfig(fixed_wait=w / args.speed), False)
        for w in args.waits]
    print(f"two-link-4-muscle, {args.samples} samples, seed {args.seed}, mock speed "
          f"{args.speed:g}x")
    print(f"{'':<22}{'samples/min':>12}{'wall s':>8}{'RMS resid N·m':>15}"
          f"{'max |θ-θcmd| rad':>18}")
    with tempfile.TemporaryDirectory() as tmp:
        for k, (name, settle, dynamic) in enumerate(configs):
            rate, resid, dtheta, wall = run(model, args.samples, args.speed, settle,
                                            Path(tmp) / f"run{k}.parquet", args.seed, dynamic)
            print(f"{name:<22}{rate:>12.1f}{wall:>8.1f}{resid:>15.4f}{dtheta:>18.4f}",
                  flush=True)


if __name__ == "__main__":
    main()
