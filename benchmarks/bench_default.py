"""Cost of the default `pimbs train` (series-elastic, Const + PINN with automatic α, prior)
against one plain run (the paper's network, Basic), same data, same process, interleaved.

    .venv/bin/python benchmarks/bench_default.py [--epochs 20000] [--n-train 30] [--threads 1]

Runs plain, default, plain, default … (``--repeats``) and prints each run's wall and CPU
seconds (one thread: CPU time is the work done, whatever else loads the machine) and the
ratio of the median CPU times. Uses a simulated two-link-4-muscle recording (ATL, 496
samples) unless --data gives one.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pimbs_learn.data import load_samples, split  # noqa: E402
from pimbs_learn.losses import REPORT_SCALE, LossConfig  # noqa: E402
from pimbs_learn.prior import load_prior  # noqa: E402
from pimbs_learn.run import Run, TrainOptions  # noqa: E402
from pimbs_learn.train import train  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--epochs", type=int, default=20000)
    ap.add_argument("--n-train", type=int, default=30)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--data", type=Path, default=None)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    data = a.data
    if data is None:
        from pimbs_arm.model import ArmModel
        from pimbs_recording.format import write_recording
        from pimbs_sim.simulate import simulate
        data = Path(tempfile.mkdtemp()) / "two-link.parquet"
        write_recording(data, *simulate(ArmModel.load("two-link-4-muscle"), 496, "atl"))
    pool = load_samples(data)
    tr, ev = split(pool, a.n_train, 0)
    plain = Run(tr, ev, LossConfig.parse("basic"), 0, True, "mlp")
    prior = load_prior(pool.robot, pool.joints, pool.muscles) if pool.robot else None
    default = Run(tr, ev, LossConfig.parse("basic+const+pinn", 1.0, "auto"), 0, True,
                  "series-elastic", prior, pool.robot if prior else None)
    opts = TrainOptions(epochs=a.epochs)
    times: dict[str, list[float]] = {"plain": [], "default": []}
    for _ in range(a.repeats):
        for name, run in (("plain", plain), ("default", default)):
            cpu = time.process_time()
            res = train(run, opts)
            cpu = time.process_time() - cpu
            times[name].append(cpu)
            print(f"{name:8s} wall {res.seconds:7.1f} s  CPU {cpu:7.1f} s  "
                  f"eval_loss {res.eval_loss * REPORT_SCALE:.4g}", flush=True)
    p, d = statistics.median(times["plain"]), statistics.median(times["default"])
    print(f"{a.epochs} epochs, N = {a.n_train}, {a.threads} thread(s): CPU plain {p:.1f} s, "
          f"default {d:.1f} s, ratio {d / p:.2f}")


if __name__ == "__main__":
    main()
