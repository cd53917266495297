"""Confusion matrix of `pimbs diagnose` on blind concealed-effect recordings.

For each robot, effect, magnitude and seed: simulate a clean reference and a "real"
recording of the same poses in which the effect is concealed together with a random
muscle-routing difference (a real arm never matches its model's routing), diagnose, and
tally the top named effect ("none" if nothing is named; "either" if nothing is named but
explanations the recording cannot tell apart are reported: counted in their own column,
neither right nor wrong, with how often the truth is among them; "unexplained" answers
likewise). Prints Markdown tables for the README and writes every case to JSON.

``--sets multi`` conceals several effects at once instead — gain errors alone, pairs and
triples (``COMBOS``) — and scores each case as a set: every concealed effect named and
nothing else, each on the right muscle or joint, the held-out fit improved; null
recordings must name nothing.

    python benchmarks/diagnosis_confusion.py --seeds 3 --samples 400 --out confusion.json
    python benchmarks/diagnosis_confusion.py --sets multi --seeds 2 --samples 400
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from pimbs_arm.model import ArmModel  # noqa: E402
from pimbs_learn.diagnosis.run import diagnose  # noqa: E402
from pimbs_recording.format import write_recording  # noqa: E402
from pimbs_sim.effects import parse_effect  # noqa: E402
from pimbs_sim.simulate import simulate  # noqa: E402

MAGNITUDES = {  # effect: (large, small)
    "tendon_friction": (0.15, 0.05),
    "link_mass": (1.3, 1.1),
    "tension_offset": (15.0, 4.0),
    "thermal_drift": (0.8, 0.25),
    "elastic_stiffness": (0.6, 0.85),
    "joint_offset": (0.04, 0.015),
}
CLASSES = ["none", *MAGNITUDES]
# Several effects at once: (label, [(effect, magnitude, where)]); where: "m" a random
# muscle, "m=" the previous effect's muscle, "j" a random joint, "" all muscles / last link.
COMBOS = [
    ("none", []),
    ("gain 15 %", [("tension_gain", 0.15, "m")]),
    ("gain 5 %", [("tension_gain", 0.05, "m")]),
    ("friction + offset", [("tendon_friction", 0.1, ""), ("tension_offset", 10.0, "m")]),
    ("friction + offset, same muscle", [("tension_offset", 10.0, "m"),
                                        ("tendon_friction", 0.1, "")]),
    ("mass + joint offset", [("link_mass", 1.4, ""), ("joint_offset", 0.04, "j")]),
    ("gain + offset", [("tension_gain", 0.15, "m"), ("tension_offset", 10.0, "m")]),
    ("drift + offset, same muscle", [("tension_offset", 10.0, "m"),
                                     ("thermal_drift", 0.5, "m=")]),
    ("friction + gain + joint offset", [("tendon_friction", 0.1, ""),
                                        ("tension_gain", 0.15, "m"),
                                        ("joint_offset", 0.04, "j")]),
    ("mass + drift + stiffness", [("link_mass", 1.3, ""), ("thermal_drift", 0.5, ""),
                                  ("elastic_stiffness", 0.7, "")]),
]


def spec_for(effect: str, magnitude: float, arm: ArmModel, rng: np.random.Generator) -> str:
    if effect in ("tension_offset",):
        return f"{effect}:{magnitude},muscles={rng.choice(arm.muscles)}"
    if effect == "joint_offset":
        return f"{effect}:{magnitude},joints={rng.choice(arm.joints)}"
    return f"{effect}:{magnitude}"


def combo_specs(parts, arm: ArmModel, rng: np.random.Generator) -> tuple[list[str], list]:
    """Conceal specs and the truth ``(effect, muscles, joints)`` of a combination."""
    specs, truth, last = [], [], None
    for effect, magnitude, where in parts:
        if where in ("m", "m="):
            muscle = last if where == "m=" else str(rng.choice(
                [m for m in arm.muscles if m not in [t[1][0] for t in truth if t[1]]]))
            specs.append(f"{effect}:{magnitude},muscles={muscle}")
            truth.append((effect, [muscle], []))
            last = muscle
        elif where == "j":
            joint = str(rng.choice(arm.joints))
            specs.append(f"{effect}:{magnitude},joints={joint}")
            truth.append((effect, [], [joint]))
        else:
            specs.append(f"{effect}:{magnitude}")
            truth.append((effect, [], []))
    return specs, truth


def run_case(arm, effect, magnitude, seed, n, routing, workdir: Path,
             specs: list[str] | None = None) -> dict:
    rng = np.random.default_rng([seed, 99])
    if specs is None:
        specs = [] if effect == "none" else [spec_for(effect, magnitude, arm, rng)]
    specs = list(specs)
    if routing:
        specs.append(f"routing:{routing}")
    paths = {}
    for name, hidden in (("sim", []), ("real", specs)):
        # same poses, independent sensor noise: a real arm never shares the simulator's
        data, meta = simulate(arm, n, "atl", seed=seed, noise_seed=seed + (name == "real") * 1000,
                              effects=tuple(parse_effect(s, seed=seed) for s in hidden))
        paths[name] = workdir / f"{name}.parquet"
        write_recording(paths[name], data, meta)
    t0 = time.perf_counter()
    result, _ = diagnose(paths["real"], paths["sim"])
    seconds = time.perf_counter() - t0
    named = [e["name"] for e in result["effects"]]
    either = [sorted({o["name"] for o in a["either"]}) for a in result.get("ambiguous", [])]
    unexplained = [u["why"] for u in result.get("unexplained", [])]
    return {"robot": arm.robot.name, "effect": effect, "magnitude": magnitude, "seed": seed,
            "concealed": specs, "named": named, "top": top_answer(named, either),
            "either": either, "unexplained": unexplained,
            "fit_before": result["fit"]["before"], "fit_after": result["fit"]["after"],
            "parameters": result["effects"][0]["parameters"] if named else {},
            "where": {e["name"]: e["muscles"] + (e["joints"] if e["name"] == "joint_offset"
                                                 else []) for e in result["effects"]},
            "residual_is_noise": result["residual"]["consistent_with_noise"],
            "seconds": seconds}


def top_answer(named: list[str], either: list[list[str]]) -> str:
    """The first answer: a named effect, "either" (explanations the recording cannot tell
    apart, nothing named before them), or "none". An "either" is neither right nor wrong:
    it is counted in its own column, with whether the truth is among its explanations."""
    if named:
        return named[0]
    return "either" if either else "none"


def score_set(case: dict, truth: list) -> dict:
    """Set-level verdict: exactly the concealed effects, each where it was concealed."""
    concealed = {t[0] for t in truth}
    named = set(case["named"])
    place = all(case["where"].get(eff) == muscles + joints
                for eff, muscles, joints in truth if (muscles or joints) and eff in named)
    unsure = {n for group in case["either"] for n in group}
    return {"set_ok": named == concealed, "place_ok": place,
            "missed": sorted(concealed - named), "extra": sorted(named - concealed),
            # nothing wrong named, the rest said to be one of several explanations
            "either_ok": bool(case["either"]) and named <= concealed
            and concealed - named <= unsure,
            "improved": case["fit_after"] < case["fit_before"] if truth else None}


def run_multi(args) -> None:
    cases = []
    with tempfile.TemporaryDirectory() as tmp:
        for robot in args.robots:
            arm = ArmModel.load(robot)
            for label, parts in COMBOS:
                for seed in range(args.seeds):
                    rng = np.random.default_rng([100 + seed, 7])
                    specs, truth = combo_specs(parts, arm, rng)
                    case = run_case(arm, label, 0.0, 100 + seed, args.samples, args.routing,
                                    Path(tmp), specs=specs)
                    case.update(score_set(case, truth), combo=label)
                    cases.append(case)
                    ok = "ok " if case["set_ok"] and case["place_ok"] else "MISS"
                    print(f"{ok} {robot:18s} {label:32s} seed {seed}: named {case['where']} "
                          f"either {case['either']} "
                          f"fit {case['fit_before']:.3f} → {case['fit_after']:.3f} "
                          f"rest noise {case['residual_is_noise']} ({case['seconds']:.1f} s)",
                          flush=True)
    args.out.write_text(json.dumps(cases, indent=1))
    print(f"\nrouting {args.routing} m, {args.samples} samples, {args.seeds} seeds per row\n")
    print("| robot | concealed | exact set named | right muscle/joint | either/or (truth "
          "among them) | unexplained | fit improved | rest consistent with noise |")
    print("|---|---|---|---|---|---|---|---|")
    for robot in args.robots:
        for label, _ in COMBOS:
            sel = [c for c in cases if c["robot"] == robot and c["combo"] == label]
            imp = "–" if label == "none" else f"{sum(bool(c['improved']) for c in sel)}/{len(sel)}"
            print(f"| {robot} | {label} | {sum(c['set_ok'] for c in sel)}/{len(sel)} | "
                  f"{sum(c['set_ok'] and c['place_ok'] for c in sel)}/{len(sel)} | "
                  f"{sum(bool(c['either']) for c in sel)} ({sum(c['either_ok'] for c in sel)})"
                  f" | {sum(bool(c['unexplained']) for c in sel)} | {imp} | "
                  f"{sum(c['residual_is_noise'] for c in sel)}/{len(sel)} |")
    hit = [c for c in cases if c["combo"] != "none"]
    print(f"\nexact set on the right muscles/joints: "
          f"{sum(c['set_ok'] and c['place_ok'] for c in hit)}/{len(hit)}; either/or answers: "
          f"{sum(bool(c['either']) for c in hit)} (truth among them in "
          f"{sum(c['either_ok'] for c in hit)}); unexplained: "
          f"{sum(bool(c['unexplained']) for c in hit)}; false alarms on "
          f"null: {sum(bool(c['named']) for c in cases if c['combo'] == 'none')}/"
          f"{sum(c['combo'] == 'none' for c in cases)}; fit improved: "
          f"{sum(bool(c['improved']) for c in hit)}/{len(hit)}; median time "
          f"{np.median([c['seconds'] for c in cases]):.1f} s")


def table(cases: list[dict], robot: str, size: str) -> str:
    rows = [c for c in cases if c["robot"] == robot and c["size"] in (size, "-")]
    head = ("| concealed \\ named | " + " | ".join(CLASSES)
            + " | other | either/or (truth among them) | unexplained |")
    lines = [head, "|" + "---|" * (len(CLASSES) + 4)]
    for truth in CLASSES:
        sel = [c for c in rows if c["effect"] == truth]
        counts = [sum(c["top"] == k for c in sel) for k in CLASSES]
        either = [c for c in sel if c["top"] == "either"]
        among = sum(truth in {n for g in c["either"] for n in g} for c in either)
        other = len(sel) - sum(counts) - len(either)
        lines.append(f"| {truth} | " + " | ".join(str(k) for k in counts) + f" | {other} | "
                     f"{len(either)} ({among}) | {sum(bool(c['unexplained']) for c in sel)} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--samples", type=int, default=400)
    ap.add_argument("--routing", type=float, default=0.002, help="m; 0 for the model routing")
    ap.add_argument("--robots", nargs="+", default=["two-link-4-muscle", "left-arm-5dof"])
    ap.add_argument("--out", type=Path, default=Path("confusion.json"))
    ap.add_argument("--sets", choices=["single", "multi"], default="single",
                    help="single: one effect per recording (confusion matrices); multi: "
                         "gain errors, pairs and triples scored as sets")
    args = ap.parse_args()
    if args.sets == "multi":
        run_multi(args)
        return
    cases = []
    with tempfile.TemporaryDirectory() as tmp:
        for robot in args.robots:
            arm = ArmModel.load(robot)
            for effect in CLASSES:
                sizes = [("-", 0.0)] if effect == "none" else list(
                    zip(("large", "small"), MAGNITUDES[effect], strict=True))
                for size, magnitude in sizes:
                    for seed in range(args.seeds):
                        case = run_case(arm, effect, magnitude, 100 + seed, args.samples,
                                        args.routing, Path(tmp))
                        case["size"] = size
                        cases.append(case)
                        ok = "ok " if case["top"] == effect else "MISS"
                        print(f"{ok} {robot:18s} {effect:18s} {size:5s} seed {seed}: "
                              f"named {case['named']} either {case['either']} fit "
                              f"{case['fit_before']:.3f} → "
                              f"{case['fit_after']:.3f} ({case['seconds']:.1f} s)", flush=True)
    args.out.write_text(json.dumps(cases, indent=1))
    for robot in args.robots:
        for size in ("large", "small"):
            print(f"\n{robot}, {size} magnitudes ({args.seeds} seeds, null row shared):\n")
            print(table(cases, robot, size))
    hits = [c for c in cases if c["effect"] != "none"]
    improved = sum(c["fit_after"] < c["fit_before"] for c in hits if c["top"] != "none")
    print(f"\ntop effect correct: {sum(c['top'] == c['effect'] for c in cases)}/{len(cases)}; "
          f"either/or: {sum(c['top'] == 'either' for c in cases)}; unexplained: "
          f"{sum(bool(c['unexplained']) for c in cases)}; "
          f"false alarms on null: {sum(c['top'] != 'none' for c in cases if c['effect'] == 'none')}"
          f"; fit improved where named: {improved}/{sum(c['top'] != 'none' for c in hits)}; "
          f"median time {np.median([c['seconds'] for c in cases]):.1f} s")
    print(summary_single(cases))


def summary_single(cases: list[dict]) -> str:
    """Set level on single-effect recordings: that effect alone (nothing on nulls)."""
    exact = sum(c["named"] == ([] if c["effect"] == "none" else [c["effect"]]) for c in cases)
    extra = [c for c in cases if c["top"] == c["effect"] and len(c["named"]) > 1]
    kinds = sorted({n for c in extra for n in c["named"][1:]})
    return (f"exact set (the concealed effect alone): {exact}/{len(cases)}; top right but more "
            f"named: {len(extra)} (extra: {', '.join(kinds) or '-'})")


if __name__ == "__main__":
    main()
