"""Train methods on a population's recordings, every run of one arm shape in one batch.

Given a population's manifest (``benchmarks/population.py``), train sizes N, seeds and
methods (``STRUCTURE:LOSS[@WEIGHT][~SCHEDULE]``, ``pimbs_learn.method_spec``), every run
(arm × N × seed × method) is trained with ``pimbs_learn.train.train_runs``, stacked: all runs
with the same numbers of joints and muscles, N, structure and schedule go into one call (at
most ``--max-batch`` runs), whatever the arms' joints and muscles are called. On a GPU a
batch costs about as much as one run; on a CPU stacking saves the per-epoch overhead.

Per seed s, the N training rows are ``pimbs_learn.data.split(recording, N, s)`` (the draw of
``pimbs train --n-train N --seed s``) and the next ``--max-eval`` rows of that draw evaluate;
each method of a seed starts from the same initial weights (seed s), so methods pair by
(arm, N, seed). One JSON line per run is appended to ``--out``; runs already there (same arm,
N, seed, method, hidden, epochs) are skipped, so an interrupted pass resumes.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/population_runner.py \\
        --manifest population/manifest.jsonl --split dev --n 5 10 30 --seeds 3 \\
        --methods se:basic+const+pinn@auto~exp se:basic~exp --hidden 256 --epochs 20000 \\
        --out population/runs.jsonl
    .venv/bin/python benchmarks/population_runner.py --summary population/runs.jsonl \\
        --base se:basic~exp --other se:basic+const+pinn@auto~exp
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pimbs_learn.data import Samples, load_samples, split  # noqa: E402
from pimbs_learn.losses import REPORT_SCALE  # noqa: E402
from pimbs_learn.method_spec import Method, parse_method  # noqa: E402
from pimbs_learn.paired import paired_change  # noqa: E402
from pimbs_learn.run import Run, TrainOptions  # noqa: E402

SPLITS = ("dev", "judge", "all")


@dataclass(frozen=True)
class Job:
    """One run to train: which arm, N, seed and method."""

    arm: dict[str, Any]  # the manifest line
    n: int
    seed: int
    method: Method

    def key(self, hidden: int, epochs: int) -> tuple:
        return run_key(self.arm["arm"], self.n, self.seed, self.method.spec, hidden, epochs)

    def group(self) -> tuple:
        """Runs that stack: shape, N, structure and schedule."""
        return (self.arm["dof"], self.arm["n_muscles"], self.n, self.method.structure,
                self.method.schedule)


def run_key(arm: str, n: int, seed: int, method: str, hidden: int, epochs: int) -> tuple:
    return (arm, int(n), int(seed), method, int(hidden), int(epochs))


def read_manifest(path: Path, which: str, arms: list[str] | None = None
                  ) -> list[dict[str, Any]]:
    """The manifest's arms of split ``which`` (dev, judge or all), recording paths made
    absolute."""
    lines = [json.loads(t) for t in path.read_text().splitlines() if t.strip()]
    out = []
    for d in lines:
        if which != "all" and d["split"] != which:
            continue
        if arms and d["arm"] not in arms:
            continue
        d["recording_path"] = str(path.parent / d["recording"])
        out.append(d)
    return sorted(out, key=lambda d: d["seed"])


def done_keys(out: Path) -> set[tuple]:
    if not out.is_file():
        return set()
    keys = set()
    for text in out.read_text().splitlines():
        if text.strip():
            r = json.loads(text)
            keys.add(run_key(r["arm"], r["n"], r["seed"], r["method"], r["hidden"],
                             r["epochs"]))
    return keys


def plan_jobs(arms: list[dict[str, Any]], ns: list[int], seeds: list[int],
              methods: list[Method], hidden: int, epochs: int, done: set[tuple]
              ) -> tuple[list[Job], list[str]]:
    """Every run not yet in ``done``, and one note per (arm, N) that cannot train."""
    jobs, notes = [], []
    for arm in arms:
        for n in ns:
            if n >= arm["rows"]:
                notes.append(f"{arm['arm']}: N = {n} leaves no evaluation rows "
                             f"({arm['rows']} rows); skipped")
                continue
            for seed in seeds:
                for m in methods:
                    job = Job(arm, n, seed, m)
                    if job.key(hidden, epochs) not in done:
                        jobs.append(job)
    return jobs, notes


def batches(jobs: list[Job], max_batch: int) -> list[list[Job]]:
    """Jobs grouped by what stacks, each group cut into batches of at most ``max_batch``."""
    groups: dict[tuple, list[Job]] = defaultdict(list)
    for j in jobs:
        groups[j.group()].append(j)
    out = []
    for key in sorted(groups):
        g = groups[key]
        out += [g[i:i + max_batch] for i in range(0, len(g), max_batch)]
    return out


def _train_once(batch: list[Job], runs: list[list[Run]], options: TrainOptions) -> list:
    """``train_runs`` of the batch's networks, each distinct one trained once, each job's
    networks merged (one network, or several averaged: ``pimbs_learn.ensemble``).

    A checked default that falls back trains exactly what Basic trains on the same cell
    (same rows, loss, structure, schedule and initial weights), so where both are in the
    batch the one result serves both; this spares the judge about a quarter of its runs.
    Networks without the torque balance train as a stack of their own: in a stack with
    physics runs each of them would pay for the torque balance's matmuls with a zero
    weight (about half of a physics network's epoch).
    """
    from pimbs_learn.ensemble import merge
    from pimbs_learn.train import train_runs

    flat = [(j, r) for j, members in zip(batch, runs, strict=True) for r in members]
    first: dict[tuple, int] = {}
    which = [first.setdefault((j.arm["arm"], j.n, r.seed, r.loss, r.structure), i)
             for i, (j, r) in enumerate(flat)]
    trained = {}
    for pinn in (True, False):
        stack = sorted({i for i in which if flat[i][1].loss.pinn == pinn})
        if stack:
            trained.update(zip(stack, train_runs([flat[i][1] for i in stack], options),
                               strict=True))
    out, at = [], 0
    for members in runs:
        out.append(merge([trained[which[at + k]] for k in range(len(members))]))
        at += len(members)
    return out


def batch_cost(batch: list[Job]) -> float:
    """A batch's relative training cost: networks × rows (the all-zero row included) ×
    muscles, about what its matmuls grow with."""
    from pimbs_learn.ensemble import members_for

    first = batch[0]
    nets = sum(members_for(j.n) if j.method.members else 1 for j in batch)
    return nets * (first.n + 1) * first.arm["n_muscles"]


def train_batch(batch: list[Job], samples: dict[str, Samples], options: TrainOptions,
                max_eval: int) -> list[dict[str, Any]]:
    """Train one stacked batch; its JSON lines."""
    from dataclasses import replace

    from pimbs_learn.ensemble import member_runs, members_for
    from pimbs_learn.selfcheck import BASIC, applies, self_check

    runs, checks = [], []
    for j in batch:
        train, evaluate = split(samples[j.arm["arm"]], j.n, j.seed, max_eval)
        run = Run(train, evaluate, j.method.loss_for(j.n), j.seed, True, j.method.structure)
        check = self_check(run) if j.method.check and applies(run) else None
        if check is not None:  # what `pimbs train` then trains: this loss, or Basic
            run = replace(run, loss=run.loss if check.keeps_physics else BASIC,
                          torque_noise=check.torque_noise_rms)
        runs.append(member_runs(run, members_for(j.n) if j.method.members else 1))
        checks.append(check)
    opts = replace(options, schedule=batch[0].method.schedule)
    t0 = time.perf_counter()
    results = _train_once(batch, runs, opts)
    seconds = time.perf_counter() - t0
    lines = []
    for j, r, check in zip(batch, results, checks, strict=True):
        truth = j.arm.get("truth", {})
        lines.append({
            "arm": j.arm["arm"], "family": j.arm["family"], "simulator": j.arm["simulator"],
            "split": j.arm["split"], "dof": j.arm["dof"], "n_muscles": j.arm["n_muscles"],
            "effects": [e["name"] for e in truth.get("effects", [])],
            "n": j.n, "seed": j.seed, "method": j.method.spec, "hidden": options.hidden,
            "epochs": options.epochs, "eval": r.eval_loss * REPORT_SCALE,
            "best_epoch": r.best_epoch, "n_eval": r.run.eval.n_samples,
            "torque_noise_rms": r.torque_noise_rms, "device": options.device,
            "seconds": seconds / len(batch), "batch_seconds": seconds,
            "batch_runs": len(batch),
            "members": None if r.members is None else len(r.members),
            "self_check": None if check is None else check.metrics()})
    return lines


def run(a: argparse.Namespace) -> None:
    import torch

    torch.set_num_threads(a.threads)
    arms = read_manifest(a.manifest, a.split, a.arms)
    methods = [parse_method(m) for m in a.methods]
    seeds = list(range(a.seed0, a.seed0 + a.seeds))
    jobs, notes = plan_jobs(arms, a.n, seeds, methods, a.hidden, a.epochs, done_keys(a.out))
    for note in notes:
        print(note, flush=True)
    todo = batches(jobs, a.max_batch)
    print(f"{len(arms)} arms ({a.split}), {len(jobs)} runs to train in {len(todo)} batches",
          flush=True)
    samples = {d["arm"]: load_samples(d["recording_path"]) for d in arms
               if any(j.arm["arm"] == d["arm"] for j in jobs)}
    options = TrainOptions(epochs=a.epochs, hidden=a.hidden, device=a.device, lr=a.lr)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()

    def write(i: int, batch: list[Job], lines: list[dict[str, Any]]) -> None:
        with a.out.open("a") as fh:
            fh.write("".join(json.dumps(line) + "\n" for line in lines))
        first = batch[0]
        print(f"batch {i + 1}/{len(todo)}: {len(batch)} runs, {first.arm['dof']} joints "
              f"{first.arm['n_muscles']} muscles N={first.n} {first.method.structure} "
              f"~{first.method.schedule}: {lines[0]['batch_seconds']:.1f} s", flush=True)

    if a.jobs <= 1:
        for i, batch in enumerate(todo):
            write(i, batch, train_batch(batch, samples, options, a.max_eval))
    else:  # one process per core, each training whole batches on its own thread(s)
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(a.jobs, initializer=torch.set_num_threads,
                                 initargs=(a.threads,)) as pool:
            # the costliest batches first, so that no core is left with one long batch at
            # the end while the other idles
            order = sorted(range(len(todo)), key=lambda i: -batch_cost(todo[i]))
            futures = {pool.submit(train_batch, todo[i], {j.arm["arm"]: samples[j.arm["arm"]]
                                                          for j in todo[i]}, options,
                                   a.max_eval): i for i in order}
            for future in as_completed(futures):
                i = futures[future]
                write(i, todo[i], future.result())
    print(f"trained {len(jobs)} runs in {time.perf_counter() - t0:.0f} s", flush=True)


def summary(path: Path, base: str, other: str, hidden: int | None = None,
            epochs: int | None = None) -> list[str]:
    """Per family/simulator and N: the paired ratio other/base. Per arm the geometric mean
    over its seeds; over arms the median, the share above 1.05 and the largest; over all
    (arm, seed) pairs ``paired_change``."""
    rows = [json.loads(t) for t in path.read_text().splitlines() if t.strip()]
    rows = [r for r in rows if (hidden is None or r["hidden"] == hidden)
            and (epochs is None or r["epochs"] == epochs)]
    by = {(r["arm"], r["n"], r["seed"], r["hidden"], r["epochs"], r["method"]): r for r in rows}
    groups: dict[tuple, dict[str, list[tuple[float, float]]]] = defaultdict(
        lambda: defaultdict(list))
    for (arm, n, seed, hid, ep, method), r in by.items():
        if method != base or (arm, n, seed, hid, ep, other) not in by:
            continue
        o = by[(arm, n, seed, hid, ep, other)]
        for fam in (f"{r['family']} on {r['simulator']}", "all"):
            groups[(fam, n, hid, ep)][arm].append((r["eval"], o["eval"]))
    out = [f"{other} / {base} (L_eval ratio; per arm: geometric mean over seeds)"]
    for (fam, n, hid, ep), per_arm in sorted(groups.items()):
        ratios = np.array([np.exp(np.mean(np.log([o / b for b, o in pairs])))
                           for pairs in per_arm.values()])
        pairs = [p for ps in per_arm.values() for p in ps]
        line = (f"{fam:22s} N={n:<3d} h={hid} e={ep}: {len(per_arm):2d} arms, "
                f"{len(pairs):3d} pairs; median {np.median(ratios):.3f}, "
                f"> 1.05 on {np.mean(ratios > 1.05):.0%}, max {ratios.max():.3f}")
        if len(pairs) >= 2:
            change = paired_change(np.array([b for b, _ in pairs]),
                                   np.array([o for _, o in pairs]))
            line += f"; paired ×{change.ratio:.3f} [{change.low:.3f}, {change.high:.3f}]"
        out.append(line)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--manifest", type=Path)
    ap.add_argument("--split", choices=SPLITS, default="dev")
    ap.add_argument("--arms", nargs="+", help="only these arms (names)")
    ap.add_argument("--n", nargs="+", type=int, default=[5, 10, 30])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--methods", nargs="+",
                    default=["se:basic+const+pinn@auto~exp", "se:basic~exp"])
    ap.add_argument("--hidden", type=int, default=256)
    ap.add_argument("--epochs", type=int, default=20000)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--device", default="cpu", help="cpu or cuda")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads per process")
    ap.add_argument("--jobs", type=int, default=1, help="processes training batches at once")
    ap.add_argument("--max-eval", type=int, default=200, help="evaluation rows per run")
    ap.add_argument("--max-batch", type=int, default=64, help="runs per stacked call")
    ap.add_argument("--out", type=Path, help="JSON lines, appended")
    ap.add_argument("--summary", type=Path, help="print the paired summary of this file")
    ap.add_argument("--base", default="se:basic~exp")
    ap.add_argument("--other", default="se:basic+const+pinn@auto~exp")
    a = ap.parse_args()
    if a.summary:
        print("\n".join(summary(a.summary, a.base, a.other)))
        return
    if a.manifest is None or a.out is None:
        ap.error("--manifest and --out are needed to train (or give --summary FILE)")
    run(a)


if __name__ == "__main__":
    main()
