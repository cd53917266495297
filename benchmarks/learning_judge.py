"""Judge `pimbs train`'s default on the judging half of a population of drawn arms.

Judging halves of ``benchmarks/population.py``'s arms, each 20 arms (via points and MJCF
on PIMBS's simulator, MJCF on MuJoCo as the plant) on which nothing was chosen: ``first``,
the odd seeds 41–79 (judged in docs/learning-notebook.md §9), ``second``, the even seeds
40–78 (§10), both of ``--seed0 0`` and ``--seed0 40``, ``third``, the even seeds 80–118
of ``--seed0 80`` (§12), ``fourth``, the even seeds 120–158 of ``--seed0 120`` (§13;
19 arms: arm150's MuJoCo plant cannot be recorded), ``fifth``, the odd seeds 121–159
of the same population (§21; 18 arms: arm127's and arm135's plants cannot be recorded),
``sixth``, the odd seeds 161–199 of ``--seed0 160`` (§22), and ``seventh``, the odd
seeds 201–239 of ``--seed0 200`` (§24).
Every cell (arm, N, seed) trains, paired (same rows, same initial weights):

* the **default** as ``pimbs train --no-prior --n-train N --seed S`` runs it: its width,
  series-elastic structure, physics terms with the automatic weight and sensor terms, exp
  schedule, and its self-check, which may fall back to Basic;
* **Basic** with the default's structure, schedule and width (``--loss basic``);
* the **paper's Basic** (1000-1000 network, constant lr, ``pimbs train --paper --loss
  basic``): in the ``cpu`` size at N = 10 with seed 0, in the ``full`` size everywhere.

Sizes: ``cpu`` (N = 5, 10, 30 × seeds 0–2 at the default's width, the paper's Basic at
N = 10, seed 0; sized for ≤ 90 minutes on two cores) and ``full`` (every cell also for the
paper's Basic and the default at the paper's width; for a GPU: ``--device cuda``). The runs
go through ``benchmarks/population_runner.py`` (stacked by arm shape, resumable), into
``OUT/runs.jsonl``; the verdict is printed against the bars the default must meet:

* the default's ratio to Basic (per arm the geometric mean over its seeds): median ≤ 0.75
  at N = 5 and 10, worse than 1.05× on ≤ 10 % of arms, never worse than 1.5×;
* the default no worse than the paper's Basic on ≥ 90 % of arms.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/learning_judge.py --population population \\
        --half second --size cpu --jobs 2 --out population/judge-second
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pimbs_learn.model import DEFAULT_HIDDEN as HIDDEN  # noqa: E402
from pimbs_learn.paired import paired_change  # noqa: E402

HALVES = {"first": [f"arm{s:03d}" for s in range(41, 80, 2)],
          "second": [f"arm{s:03d}" for s in range(40, 79, 2)],
          "third": [f"arm{s:03d}" for s in range(80, 119, 2)],
          "fourth": [f"arm{s:03d}" for s in range(120, 159, 2)],
          "fifth": [f"arm{s:03d}" for s in range(121, 160, 2)],
          "sixth": [f"arm{s:03d}" for s in range(161, 200, 2)],
          "seventh": [f"arm{s:03d}" for s in range(201, 240, 2)]}
DEFAULT = "se:basic+const+pinn@auto~exp!check,sensors,members,home"
BASIC = "se:basic~exp!members"
PAPER_BASIC = "mlp:basic"  # the paper's network and constant-lr Adam, fixed α unused
PAPER_WIDTH = 1000


def runner(args: list[str]) -> None:
    cmd = [sys.executable, str(ROOT / "benchmarks" / "population_runner.py"), *args]
    print("$", " ".join(cmd[1:]), flush=True)
    subprocess.run(cmd, check=True)


def plan(size: str) -> list[tuple[list[str], list[int], list[int], int, int]]:
    """(methods, Ns, seeds, width, runs per stacked batch on a CPU) of each runner pass.

    On a CPU the paper's 1000-wide runs go one per batch: their 4 MB layers do not stack
    (stacked, a run took about 1.2× as long per epoch on this CPU). The default's batches are
    cut at 24 runs, so that the two cores share the largest arm shape at N = 30 (42 runs in
    one batch took 25 minutes on one core while the other had nothing left to do).
    """
    passes = [([DEFAULT, BASIC], [5, 10, 30], [0, 1, 2], HIDDEN, 24),
              ([PAPER_BASIC], [10], [0], PAPER_WIDTH, 1)]
    if size == "full":
        passes += [([PAPER_BASIC, DEFAULT], [5, 10, 30], [0, 1, 2], PAPER_WIDTH, 1)]
    return passes


def _per_arm(rows: list[dict], base: str, other: str, hid_b: int, hid_o: int, n: int,
             seeds: list[int] | None = None) -> dict[str, list[tuple[float, float]]]:
    by = {(r["arm"], r["n"], r["seed"], r["method"], r["hidden"]): r for r in rows}
    out: dict[str, list[tuple[float, float]]] = defaultdict(list)
    for (arm, n_, seed, method, hid), r in by.items():
        if n_ != n or method != base or hid != hid_b or (seeds and seed not in seeds):
            continue
        o = by.get((arm, n, seed, other, hid_o))
        if o is not None:
            out[arm].append((r["eval"], o["eval"]))
    return out


def verdict(rows: list[dict], size: str) -> list[str]:
    """The bars, by family/simulator and N, and against the paper's Basic."""
    fam = {r["arm"]: f"{r['family']} on {r['simulator']}" for r in rows}
    lines = ["| arms | N | arms (pairs) | default / Basic: median | > 1.05× | max | "
             "paired change [95 % CI] | physics kept |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    ok = True
    for n in (5, 10, 30):
        per_arm = _per_arm(rows, BASIC, DEFAULT, HIDDEN, HIDDEN, n)
        for group in sorted({fam[a] for a in per_arm}) + ["all"]:
            arms = [a for a in per_arm if group == "all" or fam[a] == group]
            if not arms:
                continue
            ratio = np.array([np.exp(np.mean(np.log([o / b for b, o in per_arm[a]])))
                              for a in arms])
            pairs = [p for a in arms for p in per_arm[a]]
            ch = paired_change(np.array([b for b, _ in pairs]), np.array([o for _, o in pairs]))
            k = [r["self_check"]["physics_kept"] for r in rows if r["method"] == DEFAULT
                 and r["n"] == n and r["hidden"] == HIDDEN and r.get("self_check")
                 and (group == "all" or fam[r["arm"]] == group)]
            lines.append(f"| {group} | {n} | {len(arms)} ({len(pairs)}) | "
                         f"{np.median(ratio):.3f} | {np.mean(ratio > 1.05):.0%} | "
                         f"{ratio.max():.3f} | {ch.text()} | {np.mean(k):.0%} |")
            if group == "all":
                bar = ((np.median(ratio) <= 0.75 or n == 30) and np.mean(ratio > 1.05) <= 0.10
                       and ratio.max() <= 1.5)
                ok &= bool(bar)
    lines.append("")
    seeds = None if size == "full" else [0]
    paper = _per_arm(rows, PAPER_BASIC, DEFAULT, PAPER_WIDTH, HIDDEN, 10, seeds)
    if paper:
        r = np.array([np.exp(np.mean(np.log([o / b for b, o in paper[a]]))) for a in paper])
        lines.append(f"Against the paper's Basic (1000-1000, constant lr) at N = 10"
                     f"{'' if size == 'full' else ', seed 0'}: the default no worse on "
                     f"{np.mean(r <= 1.0):.0%} of {len(r)} arms (median ratio "
                     f"{np.median(r):.3f}, max {r.max():.3f}).")
        ok &= bool(np.mean(r <= 1.0) >= 0.9)
    lines.append(f"All bars met: {'yes' if ok else 'NO'}.")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--population", type=Path, required=True,
                    help="folder of benchmarks/population.py holding the half's seeds")
    ap.add_argument("--half", choices=sorted(HALVES), default="second",
                    help="which judging half (first: odd seeds 41-79, second: even 40-78, "
                         "third: even 80-118, fourth: even 120-158, fifth: odd 121-159, "
                         "sixth: odd 161-199, seventh: odd 201-239)")
    ap.add_argument("--size", choices=("cpu", "full"), default="cpu")
    ap.add_argument("--out", type=Path, required=True, help="folder for runs.jsonl")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--epochs", type=int, default=20000)
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    runs = a.out / "runs.jsonl"
    t0 = time.perf_counter()
    for methods, ns, seeds, width, cpu_batch in plan(a.size):
        runner(["--manifest", str(a.population / "manifest.jsonl"), "--split", "all",
                "--arms", *HALVES[a.half], "--n", *map(str, ns), "--seed0", str(seeds[0]),
                "--max-batch", str(cpu_batch if a.device == "cpu" else 64),
                "--seeds", str(len(seeds)), "--methods", *methods, "--hidden", str(width),
                "--epochs", str(a.epochs), "--jobs", str(a.jobs), "--device", a.device,
                "--out", str(runs)])
    minutes = (time.perf_counter() - t0) / 60
    rows = [json.loads(t) for t in runs.read_text().splitlines() if t.strip()]
    rows = [r for r in rows if r["epochs"] == a.epochs]
    print(f"\njudged in {minutes:.0f} min ({a.size}, {a.device}, {a.jobs} jobs)")
    print("\n".join(verdict(rows, a.size)))


if __name__ == "__main__":
    main()
