"""Fast trainer vs the straightforward reference, same data, same init, same process.

    .venv/bin/python benchmarks/bench_train.py [--epochs 1000] [--n-train 30] [--threads 2]

Prints ms/epoch of each, the ratio, the 20000-epoch time extrapolated linearly from the
measured ms/epoch (stated as such), and each trainer's selected eval loss (×1e5): the fast
one must be no worse. Uses the closed-form synthetic 2-DOF 4-muscle body (ATL-Map,
Basic+Const+PINN, α = 1e-5) unless --data gives a recording.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pimbs_learn.data import load_samples, split  # noqa: E402
from pimbs_learn.losses import REPORT_SCALE, LossConfig  # noqa: E402
from pimbs_learn.reference import train_reference  # noqa: E402
from pimbs_learn.run import Run, TrainOptions  # noqa: E402
from pimbs_learn.synthetic import synthetic_samples  # noqa: E402
from pimbs_learn.train import train  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epochs", type=int, default=1000)
    ap.add_argument("--n-train", type=int, default=30)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--loss", default="basic+const+pinn")
    ap.add_argument("--alpha", type=float, default=1e-5)
    ap.add_argument("--data", help="a recording to use instead of the synthetic body")
    ap.add_argument("--skip-reference", action="store_true")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)

    if a.data:
        tr, ev = split(load_samples(a.data), a.n_train, seed=0)
    else:
        tr = synthetic_samples(a.n_train, seed=0)
        ev = synthetic_samples(1000, seed=1)
    run = Run(tr, ev, LossConfig.parse(a.loss, a.alpha), seed=0, atl=True)
    opts = TrainOptions(epochs=a.epochs)
    print(f"ATL-Map, {a.loss}, alpha={a.alpha:g}, n_train={tr.n_samples}, "
          f"n_eval={ev.n_samples}, epochs={a.epochs}, threads={a.threads}")

    train(run, TrainOptions(epochs=20))  # warm-up (allocator, kernels)
    fast = train(run, opts)
    fast_ms = fast.seconds / a.epochs * 1e3
    print(f"fast      : {fast_ms:7.2f} ms/epoch  eval_loss {fast.eval_loss * REPORT_SCALE:.4f}"
          f"  (best epoch {fast.best_epoch})  -> 20000 epochs ≈ {fast_ms * 20:.0f} s "
          "(extrapolated)")
    if a.skip_reference:
        return
    ref = train_reference(run, opts)
    ref_ms = ref.seconds / a.epochs * 1e3
    print(f"reference : {ref_ms:7.2f} ms/epoch  eval_loss {ref.eval_loss * REPORT_SCALE:.4f}"
          f"  (best epoch {ref.best_epoch})  -> 20000 epochs ≈ {ref_ms * 20:.0f} s "
          "(extrapolated)")
    print(f"speed-up  : {ref_ms / fast_ms:.1f}x;  eval_loss fast/reference = "
          f"{fast.eval_loss / ref.eval_loss:.3f}")


if __name__ == "__main__":
    main()
