"""How a self-check rule would have chosen, on cells where both choices were trained.

Joins the population runner's runs (the physics method and Basic on the same cells) with
the self-check's evidence per cell (``benchmarks/population_signals.py``) and, for each
threshold t of the rule "keep the physics when the Gaussian process's leave-one-out length
error with torques is below t × the error without", reports per N what the checked default
would have scored against Basic: per arm the geometric mean over seeds of the ratio
(a fallback scores exactly 1, since it trains what Basic trains), then over arms the median,
the share worse than 1.05× and the worst — the bars the default must meet — and how often
the physics was kept. The oracle row (always the better of the two) bounds any rule.

    .venv/bin/python benchmarks/population_choice.py --runs population/dev_h256.jsonl \\
        --signals population/dev_signals.jsonl
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

PHYSICS = "se:basic+const+pinn@auto~exp"
BASIC = "se:basic~exp"


def cells(runs: Path, signals: Path, hidden: int | None, physics: str = PHYSICS
          ) -> list[dict]:
    """One dict per cell with both runs and the evidence: arm, n, seed, physics (the run of
    method ``physics``), basic, ratio (GP), family."""
    sig = {(r["arm"], r["n"], r["seed"]): r for r in
           map(json.loads, signals.read_text().splitlines()) if r}
    by: dict[tuple, dict] = defaultdict(dict)
    for r in map(json.loads, runs.read_text().splitlines()):
        if hidden is None or r["hidden"] == hidden:
            by[(r["arm"], r["n"], r["seed"])][r["method"]] = r
    out = []
    for key, m in sorted(by.items()):
        if physics in m and BASIC in m and key in sig:
            out.append({"arm": key[0], "n": key[1], "seed": key[2],
                        "physics": m[physics]["eval"], "basic": m[BASIC]["eval"],
                        "gp": sig[key]["ratio"],
                        "family": f"{m[BASIC]['family']} on {m[BASIC]['simulator']}"})
    return out


def score(cs: list[dict], keep) -> dict[int, tuple[float, float, float, float, int]]:
    """Per N: (median, share > 1.05, max, share kept, arms) of the per-arm ratios."""
    out = {}
    for n in sorted({c["n"] for c in cs}):
        per_arm: dict[str, list[float]] = defaultdict(list)
        kept = []
        for c in (c for c in cs if c["n"] == n):
            k = keep(c)
            kept.append(k)
            per_arm[c["arm"]].append(np.log(c["physics"] / c["basic"]) if k else 0.0)
        r = np.exp([np.mean(v) for v in per_arm.values()])
        out[n] = (float(np.median(r)), float(np.mean(r > 1.05)), float(r.max()),
                  float(np.mean(kept)), len(r))
    return out


def choose(cs: list[dict], thresholds: list[float]) -> dict[int, float]:
    """Per N, the threshold the protocol picks (docs/learning-notebook.md §10): among those
    meeting the safety bars on these arms (worse than 1.05× on ≤ 10 %, never worse than
    1.5×), the lowest median ratio, ties to the lower threshold; 0 (always Basic) where none
    meets them."""
    out: dict[int, float] = {}
    scored = {t: score(cs, lambda c, t=t: c["gp"] < t) for t in sorted(thresholds)}
    for n in sorted({c["n"] for c in cs}):
        safe = [(s[n][0], t) for t, s in scored.items() if s[n][1] <= 0.10 and s[n][2] <= 1.5]
        out[n] = min(safe)[1] if safe else 0.0
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=Path, required=True)
    ap.add_argument("--signals", type=Path, required=True)
    ap.add_argument("--hidden", type=int, default=None)
    ap.add_argument("--physics", default=PHYSICS,
                    help="the method with physics terms the check keeps or replaces by Basic")
    ap.add_argument("--thresholds", nargs="+", type=float,
                    default=[0.0, 0.5, 0.7, 0.8, 0.9, 0.95, 1.0, 1.05, 1.1, 1.2, 1.5, 2.0,
                             float("inf")])
    a = ap.parse_args()
    cs = cells(a.runs, a.signals, a.hidden, a.physics)
    print(f"{len(cs)} cells, {len({c['arm'] for c in cs})} arms")
    chosen = choose(cs, a.thresholds)
    rules = [(f"t = {t:g}", lambda c, t=t: c["gp"] < t) for t in a.thresholds]
    rules.append(("oracle", lambda c: c["physics"] < c["basic"]))
    rules.append(("chosen", lambda c: c["gp"] < chosen[c["n"]]))
    print("rule        " + "".join(f"| N={n}: median  >1.05  max  kept " for n in
                                    sorted({c['n'] for c in cs})))
    for name, keep in rules:
        s = score(cs, keep)
        print(f"{name:11s} " + "".join(f"| {m:6.3f} {w:5.0%} {x:6.3f} {k:4.0%} "
                                       for m, w, x, k, _ in s.values()))
    print("chosen per N: " + ", ".join(f"N = {n}: t = {t:g}" for n, t in chosen.items()))


if __name__ == "__main__":
    main()
