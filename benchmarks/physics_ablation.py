"""Research driver: which structure / physics weighting beats Basic, paired.

Each arm gives one 496-sample ATL recording; per seed, N samples are drawn, every method
trains on exactly those samples from the same initial weights (seed), and the rest of the
recording evaluates. Prints one JSON line per run and a summary of paired changes against
the first method (Basic). A method is STRUCTURE:LOSS[@WEIGHT][~SCHEDULE], e.g.
`se:basic+const+pinn@auto~exp` (the default of `pimbs train`, no prior); without a
schedule, the paper's constant lr. Tuning arms: two-link, five-dof (pimbs simulate).
Held-out arms: foreign (tests/foreign_arm.py) and spatial (tests/spatial_arm.py).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/physics_ablation.py --arms two-link \
        --n 5 10 --seeds 5 --epochs 4000 --methods mlp:basic se:basic+const+pinn@auto~exp
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pimbs_learn.data import load_samples, split  # noqa: E402
from pimbs_learn.losses import REPORT_SCALE, LossConfig  # noqa: E402
from pimbs_learn.method_spec import parse_method  # noqa: E402
from pimbs_learn.paired import paired_change  # noqa: E402
from pimbs_learn.run import Run, TrainOptions  # noqa: E402
from pimbs_learn.train import train_runs  # noqa: E402


def recording(arm: str, data_dir: Path) -> Path:
    """Write (once) and return the 496-sample recording of an arm."""
    path = data_dir / f"{arm}.parquet"
    if path.exists():
        return path
    data_dir.mkdir(parents=True, exist_ok=True)
    if arm in ("two-link", "five-dof", "two-link-friction", "five-dof-friction"):
        from pimbs_arm.model import ArmModel
        from pimbs_recording.format import write_recording
        from pimbs_sim.effects import parse_effect
        from pimbs_sim.simulate import simulate
        robot = "two-link-4-muscle" if arm.startswith("two") else "left-arm-5dof"
        eff = (parse_effect("tendon_friction:0.1"),) if arm.endswith("friction") else ()
        data, meta = simulate(ArmModel.load(robot), 496, "atl", seed=0, effects=eff)
        write_recording(path, data, meta)
    elif arm.startswith("foreign"):
        from tests.foreign_arm import record
        if arm.endswith("friction"):
            record(path, 496, 0, "tendon_friction", 0.1)
        else:
            record(path, 496, 0)
    elif arm.startswith("spatial"):
        from tests.spatial_arm import record
        record(path, 496, 0, friction=0.1 if arm.endswith("friction") else 0.0)
    else:
        raise SystemExit(f"unknown arm {arm}")
    return path


def method(spec: str) -> tuple[str, LossConfig, str]:
    """'se:basic+const+pinn@auto~exp' / 'mlp:basic+pinn@1e-5' -> (structure, loss, lr
    schedule); without '~' the schedule is constant (the paper's Adam)."""
    m = parse_method(spec)
    return m.structure, m.loss, m.schedule


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--arms", nargs="+", default=["two-link"])
    ap.add_argument("--n", nargs="+", type=int, default=[5, 10])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--epochs", type=int, default=4000)
    ap.add_argument("--hidden", type=int, default=1000)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--methods", nargs="+", default=["mlp:basic"])
    ap.add_argument("--data", type=Path, default=Path("/tmp/learn/data"))
    ap.add_argument("--out", type=Path, default=None, help="append JSON lines here")
    ap.add_argument("--curve-every", type=int, default=0,
                    help="add L_eval and training L_basic every K epochs to each JSON line")
    a = ap.parse_args()
    torch.set_num_threads(1)
    opts = TrainOptions(epochs=a.epochs, hidden=a.hidden, lr=a.lr, curve_every=a.curve_every)
    rows = []
    for arm in a.arms:
        pool = load_samples(recording(arm, a.data))
        for n in a.n:
            for seed in range(a.seed0, a.seed0 + a.seeds):
                tr, ev = split(pool, n, seed)
                for spec in a.methods:
                    st, loss, schedule = method(spec)
                    t0 = time.perf_counter()
                    res = train_runs([Run(tr, ev, loss, seed, True, st)],
                                     replace(opts, schedule=schedule))[0]
                    row = {"arm": arm, "n": n, "seed": seed, "method": spec,
                           "eval": res.eval_loss * REPORT_SCALE, "best_epoch": res.best_epoch,
                           "s": round(time.perf_counter() - t0, 1)}
                    if a.curve_every:
                        row.update(curve_epochs=res.curve_epochs.tolist(),
                                   curve_eval=(res.curve_eval * REPORT_SCALE).tolist(),
                                   curve_train=(res.curve_train * REPORT_SCALE).tolist())
                    rows.append(row)
                    print(json.dumps(row), flush=True)
                    if a.out:
                        with a.out.open("a") as fh:
                            fh.write(json.dumps(row) + "\n")
    summarize(rows, a.methods)


def summarize(rows: list[dict], methods: list[str]) -> None:
    base = methods[0]
    keys = sorted({(r["arm"], r["n"]) for r in rows})
    for arm, n in keys:
        sel = {m: {r["seed"]: r["eval"] for r in rows if (r["arm"], r["n"], r["method"])
                   == (arm, n, m)} for m in methods}
        seeds = sorted(sel[base])
        b = np.array([sel[base][s] for s in seeds])
        print(f"{arm} N={n}: {base} {b.mean():.4g} ± {b.std():.2g}")
        for m in methods[1:]:
            if not all(s in sel[m] for s in seeds) or len(seeds) < 2:
                continue
            o = np.array([sel[m][s] for s in seeds])
            c = paired_change(b, o)
            print(f"   {m:32s} {o.mean():.4g} ± {o.std():.2g}  mean×{c.mean_ratio:.2f}  "
                  f"paired {c.text()}")


if __name__ == "__main__":
    main()
