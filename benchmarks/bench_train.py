"""Fast trainer vs the straightforward reference, same data, same init, same process.

    .venv/bin/python benchmarks/bench_train.py [--epochs 1000] [--n-train 30] [--threads 2]

Prints ms/epoch of each, the ratio, the 20000-epoch time extrapolated linearly from the
measured ms/epoch (stated as such), and each trainer's selected eval loss (×1e5): the fast
one must be no worse. The machine is shared, so ms/epoch is given both as the mean over the
whole run and as the median of 50-epoch chunks (robust to other users' bursts); the ratio
uses the medians. Uses the closed-form synthetic 2-DOF 4-muscle body (ATL-Map,
Basic+Const+PINN, α = 1e-5) unless --data gives a recording.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pimbs_learn.data import load_samples, split  # noqa: E402
from pimbs_learn.losses import REPORT_SCALE, LossConfig  # noqa: E402
from pimbs_learn.reference import train_reference  # noqa: E402
from pimbs_learn.run import Run, TrainOptions  # noqa: E402
from pimbs_learn.synthetic import synthetic_samples  # noqa: E402
from pimbs_learn.train import train, train_runs  # noqa: E402


class ChunkTimer:
    """Progress callback that records the wall time of each chunk of epochs."""

    def __init__(self) -> None:
        self.last, self.epochs, self.ms = time.perf_counter(), 0, []

    def __call__(self, epoch: int) -> None:
        if torch.cuda.is_available():
            torch.cuda.synchronize()  # GPU work is asynchronous; time what was done
        now = time.perf_counter()
        self.ms.append((now - self.last) * 1e3 / (epoch - self.epochs))
        self.last, self.epochs = now, epoch

    @property
    def median(self) -> float:
        return statistics.median(self.ms)


def timed(trainer, run: Run, opts: TrainOptions, name: str):
    timer = ChunkTimer()
    res = trainer(run, opts, progress=timer, progress_every=CHUNK)
    mean = res.seconds / opts.epochs * 1e3
    print(f"{name:10s}: {timer.median:7.2f} ms/epoch median of chunks ({mean:.2f} mean)  "
          f"eval_loss {res.eval_loss * REPORT_SCALE:.4f} (best epoch {res.best_epoch})  "
          f"-> 20000 epochs ≈ {timer.median * 20:.0f} s (extrapolated)")
    return res, timer.median


CHUNK = 50


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epochs", type=int, default=1000)
    ap.add_argument("--n-train", type=int, default=30)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--loss", default="basic+const+pinn")
    ap.add_argument("--alpha", type=float, default=1e-5)
    ap.add_argument("--data", help="a recording to use instead of the synthetic body")
    ap.add_argument("--skip-reference", action="store_true")
    ap.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)

    if a.data:
        tr, ev = split(load_samples(a.data), a.n_train, seed=0)
    else:
        tr = synthetic_samples(a.n_train, seed=0)
        ev = synthetic_samples(1000, seed=1)
    run = Run(tr, ev, LossConfig.parse(a.loss, a.alpha), seed=0, atl=True)
    opts = TrainOptions(epochs=a.epochs, device=a.device)
    print(f"ATL-Map, {a.loss}, alpha={a.alpha:g}, n_train={tr.n_samples}, "
          f"n_eval={ev.n_samples}, epochs={a.epochs}, threads={a.threads}, "
          f"device={a.device}")

    train(run, TrainOptions(epochs=20, device=a.device))  # warm-up (allocator, kernels)
    fast, fast_ms = timed(train_one, run, opts, "fast")
    if a.skip_reference:
        return
    ref, ref_ms = timed(train_reference, run, opts, "reference")
    print(f"speed-up  : {ref_ms / fast_ms:.1f}x (medians);  eval_loss fast/reference = "
          f"{fast.eval_loss / ref.eval_loss:.4f}")


def train_one(run: Run, opts: TrainOptions, progress, progress_every: int):
    return train_runs([run], opts, progress, progress_every)[0]


if __name__ == "__main__":
    main()
