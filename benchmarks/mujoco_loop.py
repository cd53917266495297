"""The whole loop on a MuJoCo arm, through the ``pimbs`` commands a user would run.

The description is ``fixtures/mujoco/planar_2dof.xml``; the arm behind the simulated bus is
MuJoCo integrating ``planar_2dof_real.xml`` (a 29 mm shoulder pulley instead of 25 mm, links
15 % and 25 % heavier, the elbow extensor inserted 4 mm further out):

1. ``pimbs collect --plant`` a training recording of ``--train-samples`` + ``--spare`` poses
   (a pose the arm overloads or runs off is given up by the collection; a stop — safety or a
   starved mock board — is resumed with ``--resume`` and counted);
2. ``pimbs collect --plant`` NEW poses (another seed) with the geometric model: the baseline,
   and the evaluation set of ``pimbs train`` (so all training rows train);
3. ``pimbs train`` on ``--train-samples`` of its rows (defaults: series-elastic ATL-Map,
   automatic α; ``--epochs`` as given);
4. ``pimbs collect --plant --schema MODEL`` the same new poses;
5. ``pimbs estimate MODEL`` the joint angles of the new poses (beside the geometric model's),
   ``pimbs export --onnx`` and the ONNX lengths against the recorded ones;
6. ``pimbs simulate`` the description at the training poses (same seed and samples: the
   pairing the README's diagnosis walkthrough uses) and ``pimbs diagnose`` the plant
   recording against it;
7. the plant's speed from ``benchmarks/bench_mujoco_plant.py``.

Prints one markdown block. Deterministic seeds; intermediate files stay in ``--work`` and a
rerun reuses them (collections resume, a trained model is kept unless ``--retrain``).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/mujoco_loop.py --work bench-mujoco-loop
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/mujoco_loop.py --quick --work /tmp/loop-quick
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from pimbs_recording.format import read_recording

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "fixtures" / "mujoco"
DEG = 180.0 / np.pi


def pimbs(*args: str | Path, check: bool = True) -> subprocess.CompletedProcess:
    """One ``pimbs`` command as a user runs it (a fresh process)."""
    cmd = [sys.executable, "-m", "pimbs_cli.main", *map(str, args)]
    print("$ pimbs " + " ".join(map(str, args)), file=sys.stderr, flush=True)
    res = subprocess.run(cmd, capture_output=True, text=True)
    if check and res.returncode != 0:
        raise RuntimeError(f"pimbs {args[0]} failed (exit {res.returncode}):\n"
                           f"{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
    return res


def collect(out: Path, robot: Path, plant: Path, samples: int, seed: int, speed: float,
            schema: Path | None = None, stuck: int = 6) -> tuple[Path, list[str]]:
    """A complete collection on the plant; every stop is resumed and its last line kept.

    The stops are logged beside the recording (``OUT.stops.json``), so a rerun that resumes
    an earlier collection still reports them all. Gives up after ``stuck`` stops in a row
    that added no row.
    """
    args = ["collect", "--port", "virtual", "--robot", robot, "--plant", plant,
            "--samples", samples, "--seed", seed, "--mock-speed", speed, "--out", out]
    if schema is not None:
        args += ["--schema", schema]
    log = out.with_name(out.name + ".stops.json")
    stops: list[str] = json.loads(log.read_text()) if out.exists() and log.exists() else []
    without_progress = 0
    while True:
        rows = rows_in(out)
        if rows >= samples:
            return out, stops
        res = pimbs(*args, *(["--resume"] if out.exists() else []), check=False)
        if res.returncode == 0:
            return out, stops
        lines = (res.stderr.strip() or res.stdout.strip()).splitlines()
        stops.append(short_stop(lines[-1]) if lines else f"exit {res.returncode}")
        log.write_text(json.dumps(stops, indent=1) + "\n")
        print(f"  stopped: {stops[-1]}", file=sys.stderr, flush=True)
        without_progress = 0 if rows_in(out) > rows else without_progress + 1
        if without_progress >= stuck:
            raise RuntimeError(f"collection {out} stopped {stuck} times in a row without a "
                               f"new row: {stops[-stuck:]}")


def rows_in(path: Path) -> int:
    return read_recording(path).n_rows if path.exists() else 0


def given_up(path: Path, planned: int) -> int:
    """Planned poses the recording lacks (given up, or infeasible, by the collection)."""
    return planned - rows_in(path)


def short_stop(line: str) -> str:
    """The kind of stop, the muscle and the sample of a collection's one-line error."""
    head = line.removeprefix("Error: ").split(" on port ")[0].split(";")[0]
    where = re.search(r"At sample \d+ \(pose [^)]*\)", line)
    need = re.search(r"the plan (did not need|needed) that tension", line)
    return ", ".join(x for x in (head, where and where.group(0), need and need.group(0)) if x)


def pose_error_deg(path: Path, samples: np.ndarray) -> dict[str, list[float]]:
    """rms, median and largest |θ − θ_command| per joint, degrees, over the rows of
    ``samples`` (sample indices: both collections of the new poses hold the same ones)."""
    rec = read_recording(path)
    err = (np.abs(rec.theta - rec.theta_command) * DEG)[np.isin(rec.sample, samples)]
    return {"rms": np.sqrt(np.mean(err ** 2, axis=0)).tolist(),
            "median": np.median(err, axis=0).tolist(), "max": err.max(axis=0).tolist()}


def by_schema(path: Path) -> np.ndarray:
    """Samples the schema commanded (not those that fell back to the geometric plan)."""
    rec = read_recording(path)
    return rec.sample[np.asarray(rec.array("commanded_by"), str) != "geometric"]


def ratio_row(label: str, g: dict[str, list[float]], s: dict[str, list[float]]) -> str:
    def r(k: str) -> str:
        return " / ".join(f"{x / max(y, 1e-12):.1f}×" for x, y in zip(g[k], s[k], strict=True))

    return f"| {label} | {r('rms')} | {r('median')} | {r('max')} |"


def commanded_by(path: Path) -> dict[str, int]:
    rec = read_recording(path)
    if "commanded_by" not in rec.table.column_names:
        return {}
    names, counts = np.unique(np.asarray(rec.array("commanded_by"), str), return_counts=True)
    return {str(k): int(v) for k, v in zip(names, counts, strict=True)}


def geometric_length_rms_mm(robot: Path, data: Path) -> float:
    """The description's lengths at the recorded angles and tensions against the recorded."""
    from pimbs_arm.model import ArmModel

    rec = read_recording(data)
    pred = ArmModel.load(robot).length(rec.theta, rec.tension)
    return float(np.sqrt(np.mean((pred - rec.length) ** 2)) * 1e3)


def onnx_length_rms_mm(onnx: Path, data: Path) -> float:
    """The exported graph's lengths against the recorded ones (its own training rows)."""
    import onnxruntime as ort

    rec = read_recording(data)
    sess = ort.InferenceSession(str(onnx), providers=["CPUExecutionProvider"])
    pred = sess.run(["length"], {"theta": rec.theta.astype(np.float32),
                                 "tension": rec.tension.astype(np.float32)})[0]
    return float(np.sqrt(np.mean((pred - rec.length) ** 2)) * 1e3)


def diagnosis_lines(result: dict) -> list[str]:
    """What the diagnosis located and named, and the held-out fit, from its JSON."""
    lines = [f"- where: {s}" for s in result["location"]["summary"]]
    if not result["effects"]:
        lines.append("- named: nothing (no candidate passed the tests)")
    for i, e in enumerate(result["effects"], 1):
        who = ", ".join(e["muscles"] + e["joints"])
        params = "; ".join(
            f"{unit}: " + ", ".join(f"{k} {v:.4g}" for k, v in values.items()
                                    if isinstance(v, float) and k != "se")
            for unit, values in e["parameters"].items())
        lines.append(f"- named {i}: {e['name']} ({who}) {params}")
    fit = result["fit"]
    lines.append(f"- held-out fit ({fit['metric']}): {fit['before']:.4g} → {fit['after']:.4g}")
    return lines


def plant_speed() -> str:
    res = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_mujoco_plant.py")],
                         capture_output=True, text=True, check=True)
    return res.stdout.strip().splitlines()[0]


def fmt(values: list[float]) -> str:
    return " / ".join(f"{v:.2f}" for v in values)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, default=Path("bench-mujoco-loop"))
    ap.add_argument("--robot", type=Path, default=FIXTURES / "planar_2dof.xml")
    ap.add_argument("--plant", type=Path, default=FIXTURES / "planar_2dof_real.xml")
    ap.add_argument("--train-samples", type=int, default=100, help="rows the schema learns from")
    ap.add_argument("--spare", type=int, default=10,
                    help="poses planned beyond --train-samples, for those given up")
    ap.add_argument("--test-samples", type=int, default=20)
    ap.add_argument("--train-seed", type=int, default=1)
    ap.add_argument("--test-seed", type=int, default=2)
    ap.add_argument("--epochs", type=int, default=20000, help="pimbs train's default")
    ap.add_argument("--mock-speed", type=float, default=5.0)
    ap.add_argument("--retrain", action="store_true")
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: 30 training samples (the diagnosis's minimum), 3 new "
                         "poses, 300 epochs, no plant-speed benchmark")
    a = ap.parse_args()
    if a.quick:
        a.train_samples, a.test_samples, a.epochs = 30, 3, 300
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    a.work.mkdir(parents=True, exist_ok=True)
    w, started = a.work, time.perf_counter()
    reused = any(p.exists() for p in (w / "train.parquet", w / "new-geometric.parquet")) or (
        not a.retrain and any(p.exists() for p in (w / "model" / "model.json",
                                                    w / "new-schema.parquet")))

    planned = a.train_samples + a.spare
    train, train_stops = collect(w / "train.parquet", a.robot, a.plant, planned,
                                 a.train_seed, a.mock_speed)
    n_train = min(a.train_samples, rows_in(train))
    geom, geom_stops = collect(w / "new-geometric.parquet", a.robot, a.plant, a.test_samples,
                               a.test_seed, a.mock_speed)
    model = w / "model"
    if a.retrain or not (model / "model.json").exists():
        pimbs("train", train, "--eval", geom, "--n-train", n_train, "--epochs", a.epochs,
              "--threads", 1,
              "--out", model, "--json", w / "train.json", "--force")
    trained = json.loads((w / "train.json").read_text())
    learned = w / "new-schema.parquet"
    if a.retrain and learned.exists():
        learned.unlink()
    learned, schema_stops = collect(learned, a.robot, a.plant, a.test_samples, a.test_seed,
                                    a.mock_speed, schema=model)
    pimbs("estimate", model, geom, "--robot", a.robot, "--json", w / "estimate.json", "--force")
    est = json.loads((w / "estimate.json").read_text())
    pimbs("export", model, "--onnx", w / "model.onnx", "--force")
    sim = w / "sim.parquet"
    pimbs("simulate", "--robot", a.robot, "--samples", planned, "--seed", a.train_seed,
          "--out", sim, "--force")
    pimbs("diagnose", train, "--reference", sim, "--json", w / "diagnose.json", "--force")
    diag = json.loads((w / "diagnose.json").read_text())
    speed = None if a.quick else plant_speed()

    joints = read_recording(geom).joints
    both = np.intersect1d(read_recording(geom).sample, read_recording(learned).sample)
    g, s = pose_error_deg(geom, both), pose_error_deg(learned, both)
    mine = np.intersect1d(by_schema(learned), both)
    g_mine, s_mine = pose_error_deg(geom, mine), pose_error_deg(learned, mine)
    by = commanded_by(learned)
    epochs = trained.get("epochs", a.epochs)
    kept = trained.get("best_epoch", trained.get("epoch_kept"))
    rel = lambda p: os.path.relpath(p, ROOT)  # noqa: E731
    out = [
        "```",
        f"description {rel(a.robot)}; plant (MuJoCo, mj_step) {rel(a.plant)}; "
        f"--mock-speed {a.mock_speed:g}",
        f"1. collect: {read_recording(train).n_rows} of {planned} planned poses recorded "
        f"(seed {a.train_seed}; {given_up(train, planned)} given up by the collection), "
        f"{len(train_stops)} stops resumed" + "".join(f"\n     stop: {x}" for x in train_stops),
        f"2. train: ATL-Map defaults, {epochs} epochs"
        + (f" (kept epoch {kept})" if kept is not None else "")
        + f", {trained.get('seconds', float('nan')):.0f} s; {n_train} rows train; length "
        f"error on the new poses "
        f"{trained.get('eval_rms_mm', float('nan')):.3f} mm rms (geometric model "
        f"{geometric_length_rms_mm(a.robot, geom):.3f} mm)",
        f"3. {len(both)} new poses (seed {a.test_seed}) that both collections hold "
        f"({given_up(geom, a.test_samples)} given up with the geometric model, "
        f"{given_up(learned, a.test_samples)} with the schema) on the plant, "
        f"pose error |θ − θ_command| [°, {' / '.join(joints)}]:",
        "| commanded by | rms | median | max |",
        "|---|---|---|---|",
        f"| geometric model ({len(geom_stops)} stops) | {fmt(g['rms'])} | {fmt(g['median'])} "
        f"| {fmt(g['max'])} |",
        f"| learned schema ({', '.join(f'{v} {k}' for k, v in by.items())}; "
        f"{len(schema_stops)} stops) | {fmt(s['rms'])} | {fmt(s['median'])} | "
        f"{fmt(s['max'])} |",
        ratio_row("geometric ÷ schema", g, s),
        *([] if len(mine) == len(both) else [
            f"| geometric model, the {len(mine)} poses the schema commanded | "
            f"{fmt(g_mine['rms'])} | {fmt(g_mine['median'])} | {fmt(g_mine['max'])} |",
            f"| learned schema, the same {len(mine)} poses | {fmt(s_mine['rms'])} | "
            f"{fmt(s_mine['median'])} | {fmt(s_mine['max'])} |",
            ratio_row(f"geometric ÷ schema, those {len(mine)}", g_mine, s_mine)]),
        f"4. estimate (joint angles of the new poses from lengths and tensions) [° rms]: "
        f"schema {fmt(est['rms_error_deg'])}, geometric {fmt(est['geometric_rms_error_deg'])}",
        f"   export --onnx: ONNX lengths vs recorded on the training rows "
        f"{onnx_length_rms_mm(w / 'model.onnx', train):.3f} mm rms",
        f"5. diagnose plant recording vs simulate of the description (seed {a.train_seed}, "
        f"{diag['rows']} paired samples):",
        *[f"   {x}" for x in diagnosis_lines(diag)],
    ]
    if speed:
        out.append(f"6. plant speed (benchmarks/bench_mujoco_plant.py): {speed}")
    out += [f"wall time of this run {time.perf_counter() - started:.0f} s"
            + (" (steps reused from --work not counted)" if reused else ""), "```"]
    print("\n".join(out))


if __name__ == "__main__":
    main()
