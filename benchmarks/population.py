"""A population of drawn tendon-driven arms and their recordings, from two simulators.

Writes, for arms with seeds SEED0 .. SEED0+ARMS-1, into OUT:

    arms/armNNN/          the arm's description (URDF + muscle file, or an MJCF), and on
                          MuJoCo the plant MJCF when the plant differs from the description
    recordings/armNNN.parquet            the recording (ATL-Map, SAMPLES planned poses)
    recordings/armNNN.reference.parquet  the description simulated at the same seed, clean
                                         (pairs by `sample`, for `pimbs diagnose --reference`)
    manifest.jsonl        one line per arm: family, simulator, split, shape, drawn parameters,
                          the concealed truth (sensors, effects), file hashes, seconds

The layout is fixed before any method runs on it (``pimbs_sim.population.family_of``,
``split_of``): seeds 2k and 2k+1 share family and simulator (k mod 4 = 0, 1: via points on
PIMBS's simulator; 2: MJCF on PIMBS's simulator; 3: MJCF on MuJoCo as the plant); even seeds
are the development half, odd seeds the judging half. 40 arms are 20 / 10 / 10, each half
10 / 5 / 5: both simulators and both families in both halves, the MuJoCo arms on both
simulators (the same kind of description run by physics nobody here wrote, and by ours), and
most arms on the cheaper simulator.

Cached: an arm whose manifest line matches the settings and whose files still have the
hashes recorded is not made again. Every recording is integrated to rest as fast as the CPU
allows (no bus, no clock). An arm whose MuJoCo plant blows up while recording gets no
manifest line; the run names it and goes on.

    OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python benchmarks/population.py \\
        --arms 40 --out population --samples 230 --jobs 2
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pimbs_learn.data import file_sha256  # noqa: E402
from pimbs_sim.population import arm_name, family_of, split_of  # noqa: E402

VERSION = 1  # of what this script writes: a change re-makes every arm
MAP = "atl"


def settings_key(seed: int, samples: int) -> str:
    """What an arm's files depend on (beyond the code's VERSION)."""
    return hashlib.sha256(json.dumps([VERSION, seed, samples, MAP, family_of(seed)])
                          .encode()).hexdigest()[:16]


def make_one(seed: int, out: Path, samples: int) -> dict[str, Any]:
    """Draw, write and record arm ``seed``; its manifest line."""
    from pimbs_recording.format import write_recording
    from pimbs_sim.conditions import draw_conditions, write_plant
    from pimbs_sim.population import make_arm
    from pimbs_sim.simulate import simulate

    t0 = time.perf_counter()
    family, simulator = family_of(seed)
    name = arm_name(seed)
    spec = make_arm(seed, family, out / "arms" / name, samples)
    t_arm = time.perf_counter() - t0
    arm = spec.load()
    cond = draw_conditions(spec, simulator)
    rec_dir = out / "recordings"
    rec_dir.mkdir(parents=True, exist_ok=True)
    recording, reference = rec_dir / f"{name}.parquet", rec_dir / f"{name}.reference.parquet"
    line: dict[str, Any] = {}
    if simulator == "ours":
        data, meta = simulate(arm, samples, MAP, seed=seed, effects=cond.sim_effects(),
                              noise=cond.noise, sensors=cond.sensors)
        plant = None
        skipped: list[int] = []
    else:
        from pimbs_hw.mock.mujoco_recording import record_plant

        plant = write_plant(spec.mjcf, cond.plant_changes(),
                            spec.mjcf.with_name(f"{name}.plant.xml"))
        data, meta, stats = record_plant(arm, plant, samples, MAP, seed=seed,
                                         effects=cond.sim_effects(), sensors=cond.sensors,
                                         noise=cond.noise)
        skipped = stats.skipped
        line["plant_stats"] = stats.to_json()
    meta["created"] = "2026-01-01T00:00:00Z"  # fixed: the same seed writes the same bytes
    meta["generator"] = "pimbs population"
    write_recording(recording, data, meta)
    ref_data, ref_meta = simulate(arm, samples, MAP, seed=seed)
    ref_meta["created"] = meta["created"]
    write_recording(reference, ref_data, ref_meta)
    rows = int(len(data["sample"]))
    line.update({
        "arm": name, "seed": seed, "split": split_of(seed), "family": family,
        "simulator": simulator, "dof": spec.dof, "n_muscles": spec.n_muscles,
        "joints": list(spec.joints), "muscles": list(spec.muscles), "samples": samples,
        "rows": rows, "skipped": skipped, "map": MAP, "key": settings_key(seed, samples),
        "description": _rel(spec.description, out), "plant": _rel(plant, out) if plant else None,
        "recording": _rel(recording, out), "reference": _rel(reference, out),
        "sha256": {"recording": file_sha256(recording), "reference": file_sha256(reference),
                   "description": file_sha256(spec.description),
                   **({"plant": file_sha256(plant)} if plant else {})},
        "truth": cond.to_json(), "tries": spec.tries, "replaced": spec.replaced,
        "params": spec.params,
        "seconds": {"arm": round(t_arm, 2), "total": round(time.perf_counter() - t0, 2)}})
    return line


def _rel(path: Path, out: Path) -> str:
    return str(Path(path).resolve().relative_to(out.resolve()))


def cached(line: dict[str, Any] | None, seed: int, out: Path, samples: int) -> bool:
    """The manifest line is for these settings and its files are unchanged."""
    if not line or line.get("key") != settings_key(seed, samples):
        return False
    for what in ("recording", "reference", "description", "plant"):
        if what == "plant" and not line.get("plant"):
            continue
        path = out / line[what]
        if not path.is_file() or file_sha256(path) != line["sha256"][what]:
            return False
    return True


def read_manifest(out: Path) -> dict[str, dict[str, Any]]:
    path = out / "manifest.jsonl"
    if not path.is_file():
        return {}
    return {d["arm"]: d for d in map(json.loads, path.read_text().splitlines()) if d}


def write_manifest(out: Path, lines: dict[str, dict[str, Any]]) -> None:
    from pimbs_recording.atomic import atomic_file

    text = "".join(json.dumps(lines[k], sort_keys=True) + "\n"
                   for k in sorted(lines, key=lambda a: lines[a]["seed"]))
    with atomic_file(out / "manifest.jsonl") as fh:
        fh.write(text.encode())


def summary_line(d: dict[str, Any], status: str) -> str:
    from pimbs_sim.conditions import describe

    return (f"{d['arm']} {d['split']:5s} {d['family']:8s} on {d['simulator']:6s} "
            f"dof {d['dof']} muscles {d['n_muscles']:2d} rows {d['rows']:3d} "
            f"effects {describe(d['truth']['effects'])}; {status}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--arms", type=int, default=40)
    ap.add_argument("--seed0", type=int, default=0)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--samples", type=int, default=230)
    ap.add_argument("--jobs", type=int, default=1, help="worker processes")
    a = ap.parse_args()
    out = a.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    lines = read_manifest(out)
    seeds = range(a.seed0, a.seed0 + a.arms)
    todo = [s for s in seeds if not cached(lines.get(arm_name(s)), s, out, a.samples)]
    for s in seeds:
        if s not in todo:
            print(summary_line(lines[arm_name(s)], "cached"), flush=True)
    t0 = time.perf_counter()
    failed: list[str] = []
    with ProcessPoolExecutor(max_workers=max(1, a.jobs)) as pool:
        futures = {pool.submit(make_one, s, out, a.samples): s for s in todo}
        for future, s in futures.items():
            try:
                d = future.result()
            except FloatingPointError as e:  # the plant blew up: no recording, say so
                failed.append(arm_name(s))
                if lines.pop(arm_name(s), None) is not None:  # an older line is not this arm
                    write_manifest(out, lines)
                print(f"{arm_name(s)} not recorded: {e}", flush=True)
                continue
            lines[d["arm"]] = d
            write_manifest(out, lines)
            print(summary_line(d, f"{d['seconds']['total']:.1f} s"), flush=True)
    wall = time.perf_counter() - t0
    made = [lines[arm_name(s)] for s in todo if arm_name(s) not in failed]
    cpu = sum(d["seconds"]["total"] for d in made)
    seeds = [s for s in seeds if arm_name(s) not in failed]
    by = {}
    for s in seeds:
        d = lines[arm_name(s)]
        by.setdefault((d["split"], d["family"], d["simulator"]), []).append(d["arm"])
    print("layout: " + "; ".join(f"{k[0]} {k[1]} on {k[2]}: {len(v)}"
                                 for k, v in sorted(by.items())))
    shapes: dict[tuple, dict[str, int]] = {}
    for s in seeds:
        d = lines[arm_name(s)]
        shapes.setdefault((d["dof"], d["n_muscles"]), {"dev": 0, "judge": 0})[d["split"]] += 1
    print("shapes (joints, muscles): " + "; ".join(
        f"{k[0]}x{k[1]}: {v['dev']} dev + {v['judge']} judge" for k, v in sorted(shapes.items())))
    print(f"made {len(made)} arms in {wall:.0f} s wall ({cpu:.0f} s of work, "
          f"{a.jobs} job(s)); {a.arms - len(made) - len(failed)} cached; "
          f"{len(failed)} not recorded{' (' + ', '.join(failed) + ')' if failed else ''}; "
          f"manifest {out / 'manifest.jsonl'}")


if __name__ == "__main__":
    main()
