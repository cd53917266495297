"""The self-check's evidence for every (arm, N, seed) of a population, without training.

For the training rows the population runner draws (``pimbs_learn.data.split(recording, N,
seed)``), fit the Gaussian process of lengths and torques (:mod:`pimbs_learn.noise`) and
write its leave-one-sample-out length errors with and without the torques, one JSON line
per cell. Joined with the runner's L_eval of the default and of Basic on the same cells,
these say how well a rule on this evidence would have chosen between them
(``benchmarks/population_choice.py``).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/population_signals.py \\
        --manifest population/manifest.jsonl --split dev --n 5 10 30 --seeds 3 \\
        --out population/signals.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from population_runner import SPLITS, read_manifest  # noqa: E402

from pimbs_learn.data import load_samples, split  # noqa: E402
from pimbs_learn.noise import estimate_noise  # noqa: E402
from pimbs_learn.selfcheck import SelfCheck  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--manifest", type=Path, required=True)
    ap.add_argument("--split", choices=SPLITS, default="dev")
    ap.add_argument("--arms", nargs="+", help="only these arms (names)")
    ap.add_argument("--n", nargs="+", type=int, default=[5, 10, 30])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--out", type=Path, required=True, help="JSON lines, appended")
    ap.add_argument("--sensors", action="store_true",
                    help="the evidence with the sensor terms allowed (what the check of a "
                         "'!check,sensors' method reads)")
    a = ap.parse_args()
    import torch

    torch.set_num_threads(1)
    done = set()
    if a.out.is_file():
        done = {(r["arm"], r["n"], r["seed"]) for r in map(json.loads, a.out.read_text()
                                                          .splitlines()) if r}
    for arm in read_manifest(a.manifest, a.split, a.arms):
        pool = load_samples(arm["recording_path"])
        for n in a.n:
            for seed in range(a.seed0, a.seed0 + a.seeds):
                if (arm["arm"], n, seed) in done:
                    continue
                tr, _ = split(pool, n, seed)
                t0 = time.perf_counter()
                e = estimate_noise(tr.theta, tr.tension, tr.length, tr.tau, seed=seed,
                                   sensors=a.sensors)
                line = {"arm": arm["arm"], "n": n, "seed": seed, "family": arm["family"],
                        "simulator": arm["simulator"], "split": arm["split"],
                        "torque_rms": e.torque_rms, "length_rms": e.length_rms,
                        "loo_with": e.loo_with_torque.tolist(),
                        "loo_without": e.loo_without_torque.tolist(),
                        "ratio": SelfCheck.from_estimate(e, 1.0).ratio,  # what the check compares
                        "wins": float(np.mean(e.loo_with_torque < e.loo_without_torque)),
                        "seconds": round(time.perf_counter() - t0, 2)}
                with a.out.open("a") as fh:
                    fh.write(json.dumps(line) + "\n")
                print(f"{arm['arm']} N={n} seed {seed}: ratio {line['ratio']:.3f} "
                      f"({line['seconds']} s)", flush=True)


if __name__ == "__main__":
    main()
