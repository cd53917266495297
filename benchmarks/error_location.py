"""Where in (θ, f) the learned schema's error grows ("why, measured").

Per arm and seed, N samples train the paper's network with Basic and the default (series-
elastic, Const + PINN, automatic α with the evidence floor, lr decaying); every other sample
of the 496-sample recording is binned by its distance to the nearest training pose (θ
scaled by the training set's max |θ| per joint) and, separately, by how far its tensions lie
outside the training tensions' range (N, worst muscle). Prints the mean squared length
error per bin (×1e5 m², as L_eval) for each method, over seeds.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/error_location.py --arms foreign \
        foreign-friction --n 10 --seeds 3 --epochs 20000
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from physics_ablation import method, recording  # noqa: E402

from pimbs_learn.data import load_samples, split  # noqa: E402
from pimbs_learn.io import schema_from_result  # noqa: E402
from pimbs_learn.losses import REPORT_SCALE  # noqa: E402
from pimbs_learn.model import Scaling  # noqa: E402
from pimbs_learn.run import Run, TrainOptions  # noqa: E402
from pimbs_learn.train import train_runs  # noqa: E402

POSE_EDGES = (0.0, 0.25, 0.5, 0.75, 1.0, np.inf)  # nearest-pose distance, scaled θ
TENSION_EDGES = (-np.inf, 0.0, 10.0, 30.0, np.inf)  # N outside the training range


def locate(tr, ev) -> tuple[np.ndarray, np.ndarray]:
    """(nearest-training-pose distance, N outside the training tension range) per eval row."""
    th_s = Scaling.from_data(tr.theta, None, tr.length).theta  # the network's θ scale
    d = np.linalg.norm((ev.theta[:, None] - tr.theta[None]) / th_s, axis=-1).min(axis=1)
    lo, hi = tr.tension.min(axis=0), tr.tension.max(axis=0)
    out = np.maximum(lo - ev.tension, ev.tension - hi).max(axis=1)
    return d, out


def binned(err: np.ndarray, where: np.ndarray, edges) -> list[tuple[int, float]]:
    idx = np.digitize(where, edges[1:-1])
    return [(int((idx == b).sum()), float(err[idx == b].mean()) if (idx == b).any() else
             float("nan")) for b in range(len(edges) - 1)]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--arms", nargs="+", default=["foreign"])
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--epochs", type=int, default=20000)
    ap.add_argument("--hidden", type=int, default=1000)
    ap.add_argument("--methods", nargs="+",
                    default=["mlp:basic", "se:basic+const+pinn@auto~exp"])
    ap.add_argument("--data", type=Path, default=Path("/tmp/learn/data"))
    a = ap.parse_args()
    torch.set_num_threads(1)
    opts = TrainOptions(epochs=a.epochs, hidden=a.hidden)
    for arm in a.arms:
        pool = load_samples(recording(arm, a.data))
        errs: dict[str, list[np.ndarray]] = {m: [] for m in a.methods}
        pose, tens = [], []
        for seed in range(a.seeds):
            tr, ev = split(pool, a.n, seed)
            d, out = locate(tr, ev)
            pose.append(d)
            tens.append(out)
            for spec in a.methods:
                st, loss, schedule = method(spec)
                res = train_runs([Run(tr, ev, loss, seed, True, st)],
                                 replace(opts, schedule=schedule))[0]
                pred = schema_from_result(res).length(ev.theta, ev.tension)
                errs[spec].append(((pred - ev.length) ** 2).mean(axis=1) * REPORT_SCALE)
        d_all, t_all = np.concatenate(pose), np.concatenate(tens)
        for name, where, edges in (("nearest training pose (scaled θ)", d_all, POSE_EDGES),
                                   ("tension outside training range (N)", t_all,
                                    TENSION_EDGES)):
            print(f"{arm} N={a.n}, {a.seeds} seeds — error by {name}")
            labels = [f"[{lo:g}, {hi:g})" for lo, hi in zip(edges[:-1], edges[1:],
                                                              strict=True)]
            print("  bin".ljust(14) + "".join(f"{b:>16s}" for b in labels))
            counts = binned(np.zeros_like(where), where, edges)
            print("  rows".ljust(14) + "".join(f"{c:>16d}" for c, _ in counts))
            for spec in a.methods:
                e = np.concatenate(errs[spec])
                vals = binned(e, where, edges)
                print(f"  {spec[:12]:12s}" + "".join(f"{v:>16.4g}" for _, v in vals))


if __name__ == "__main__":
    main()
