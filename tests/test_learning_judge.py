"""The learning judge's verdict: the bars the default must meet, computed from the runs as
written (per arm the geometric mean over seeds of the default's L_eval over Basic's)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _judge():
    spec = importlib.util.spec_from_file_location(
        "learning_judge", ROOT / "benchmarks" / "learning_judge.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def _rows(judge, ratios: dict[int, list[float]], paper: float = 2.0) -> list[dict]:
    """Runs of 10 arms with these default/Basic ratios per N (every seed alike), and the
    paper's Basic at ``paper`` × Basic's L_eval at N = 10, seed 0."""
    rows = []
    for n, per_arm in ratios.items():
        for i, ratio in enumerate(per_arm):
            for seed in range(3):
                base = {"arm": f"arm{i:03d}", "family": "viapoint", "simulator": "ours",
                        "n": n, "seed": seed, "epochs": 20000}
                rows.append({**base, "method": judge.BASIC, "hidden": judge.HIDDEN,
                             "eval": 1.0, "self_check": None})
                rows.append({**base, "method": judge.DEFAULT, "hidden": judge.HIDDEN,
                             "eval": ratio, "self_check": {"physics_kept": ratio != 1.0}})
                if n == 10 and seed == 0:
                    rows.append({**base, "method": judge.PAPER_BASIC,
                                 "hidden": judge.PAPER_WIDTH, "eval": paper,
                                 "self_check": None})
    return rows


def test_the_verdict_holds_each_bar():
    judge = _judge()
    good = [0.5] * 8 + [1.0, 1.04]
    ok = _rows(judge, {5: good, 10: good, 30: good})
    assert judge.verdict(ok, "cpu")[-1] == "All bars met: yes."
    # one arm 1.6x worse at N = 30, where the median bar does not apply
    worst = _rows(judge, {5: good, 10: good, 30: [*good[:-1], 1.6]})
    assert judge.verdict(worst, "cpu")[-1] == "All bars met: NO."
    # two of ten arms above 1.05x
    many = _rows(judge, {5: good, 10: [0.5] * 8 + [1.1, 1.1], 30: good})
    assert judge.verdict(many, "cpu")[-1] == "All bars met: NO."
    # a median of 0.8 at N = 5
    median = _rows(judge, {5: [0.8] * 10, 10: good, 30: good})
    lines = judge.verdict(median, "cpu")
    assert lines[-1] == "All bars met: NO." and any("| all | 5 |" in x and "0.800" in x
                                                     for x in lines)
    # the paper's Basic better than the default on most arms
    paper = _rows(judge, {5: good, 10: good, 30: good}, paper=0.4)
    assert judge.verdict(paper, "cpu")[-1] == "All bars met: NO."
