"""Proof on the mock bus: poses commanded and joint angles estimated with a learned schema.

The simulated arm carries concealed effects (default: tendon routing 4 mm off the model,
plus whatever ``--conceal`` adds, e.g. link mass and tendon friction). Everything goes
through the ``pimbs`` commands a user would run:

1. ``pimbs collect`` a training recording (geometric commands) and, with another seed, a
   test recording of new poses (geometric commands: the baseline);
2. for each size n: ``pimbs train`` on the first n training rows (defaults, evaluated on the
   test poses), ``pimbs collect --schema`` the same new poses, ``pimbs estimate`` the joint
   angles of the test recording, ``pimbs export --onnx`` and its lengths on its own
   training rows;
3. one table: length error on new poses, pose error, joint-angle estimation error, each for
   the geometric model and the learned schemas.

    nice -n 10 .venv/bin/python benchmarks/use_schema.py --work bench-use \\
        --conceal link_mass:1.2 --conceal tendon_friction:0.05

Intermediate files are kept in ``--work``; a rerun reuses the recordings already there
(collections resume) and retrains only with ``--retrain``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from pimbs_arm.model import ArmModel
from pimbs_recording.format import read_recording, write_recording

DEG = 180.0 / np.pi


def pimbs(*args: str | Path, check: bool = True) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "pimbs_cli.main", *map(str, args)]
    print("$ pimbs " + " ".join(map(str, args)), flush=True)
    res = subprocess.run(cmd, capture_output=True, text=True)
    if check and res.returncode != 0:
        raise RuntimeError(f"pimbs {args[0]} failed:\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
    return res


def collect(out: Path, samples: int, seed: int, conceal: list[str], speed: float,
            schema: Path | None = None) -> Path:
    """A complete collection; a stop on this loaded machine (watchdog) is resumed."""
    args = ["collect", "--port", "virtual", "--samples", samples, "--seed", seed,
            "--mock-speed", speed, "--out", out]
    for c in conceal:
        args += ["--conceal", c]
    if schema is not None:
        args += ["--schema", schema]
    for _ in range(6):
        res = pimbs(*args, *(["--resume"] if out.exists() else []), check=False)
        if res.returncode == 0:
            return out
        print(res.stderr.strip().splitlines()[-1] if res.stderr.strip() else res.stdout[-300:])
    raise RuntimeError(f"collection {out} did not complete")


def first_rows(src: Path, n: int, out: Path) -> Path:
    rec = read_recording(src)
    write_recording(out, rec.table.slice(0, n), rec.meta)
    return out


def pose_rms_deg(path: Path) -> np.ndarray:
    rec = read_recording(path)
    return np.sqrt(np.mean((rec.theta - rec.theta_command) ** 2, axis=0)) * DEG


def length_rms_mm(predicted: np.ndarray, measured: np.ndarray) -> float:
    return float(np.sqrt(np.mean((predicted - measured) ** 2)) * 1e3)


def onnx_lengths(path: Path, theta: np.ndarray, tension: np.ndarray) -> np.ndarray:
    import onnxruntime as ort

    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return sess.run(["length"], {"theta": theta.astype(np.float32),
                                 "tension": tension.astype(np.float32)})[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, default=Path("bench-use"))
    ap.add_argument("--routing", type=float, default=0.004, help="m, via-point shifts")
    ap.add_argument("--arm-seed", type=int, default=21, help="which routing (the arm)")
    ap.add_argument("--conceal", action="append", default=[],
                    help="further concealed effects, e.g. link_mass:1.2")
    ap.add_argument("--sizes", default="50,100,200")
    ap.add_argument("--train-samples", type=int, default=200,
                    help="training collection; the schemas use its first --sizes rows")
    ap.add_argument("--test-samples", type=int, default=20)
    ap.add_argument("--train-seed", type=int, default=31)
    ap.add_argument("--test-seed", type=int, default=32)
    ap.add_argument("--epochs", type=int, default=20000)
    ap.add_argument("--mock-speed", type=float, default=10.0)
    ap.add_argument("--retrain", action="store_true")
    ap.add_argument("--table", action="store_true", help="only print the table of --work")
    a = ap.parse_args()
    if a.table:
        r = json.loads((a.work / "results.json").read_text())
        print(table(r, read_recording(a.work / "test.parquet").joints))
        return
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    a.work.mkdir(parents=True, exist_ok=True)
    conceal = [f"routing:{a.routing},seed={a.arm_seed}", *a.conceal]
    sizes = [int(s) for s in a.sizes.split(",")]

    train_all = collect(a.work / "train.parquet", max(a.train_samples, *sizes), a.train_seed,
                        conceal, a.mock_speed)
    test = collect(a.work / "test.parquet", a.test_samples, a.test_seed, conceal, a.mock_speed)
    rec = read_recording(test)
    arm = ArmModel.load(rec.robot)
    saved = a.work / "results.json"  # sizes run before (e.g. with other --epochs) are kept
    before = json.loads(saved.read_text())["schemas"] if saved.exists() else {}
    results = {"conceal": conceal, "test_samples": rec.n_rows,
               "geometric": {"length_rms_mm": length_rms_mm(arm.length(rec.theta, rec.tension),
                                                            rec.length),
                             "pose_rms_deg": pose_rms_deg(test).tolist()},
               "schemas": before}
    for n in sizes:
        data = first_rows(train_all, n, a.work / f"train-{n}.parquet")
        model = a.work / f"model-{n}"
        if a.retrain or not (model / "model.json").exists():
            pimbs("train", data, "--eval", test, "--epochs", a.epochs, "--threads", 1,
                  "--out", model, "--json", a.work / f"train-{n}.json", "--force")
        from pimbs_learn import load_body_schema

        schema = load_body_schema(model)
        commanded = a.work / f"test-schema-{n}.parquet"
        if a.retrain and commanded.exists():
            commanded.unlink()
        collect(commanded, a.test_samples, a.test_seed, conceal, a.mock_speed, schema=model)
        est = a.work / f"estimate-{n}.json"
        pimbs("estimate", model, test, "--json", est, "--force")
        angles = json.loads(est.read_text())
        onnx = a.work / f"model-{n}.onnx"
        pimbs("export", model, "--onnx", onnx, "--force")
        tr = read_recording(data)
        commanded_rec = read_recording(commanded)
        results["schemas"][str(n)] = {
            "n_train": tr.n_rows, "epochs": a.epochs,
            "structure": schema.meta.get("structure", "mlp"),
            "length_rms_mm": length_rms_mm(schema.length(rec.theta, rec.tension), rec.length),
            "pose_rms_deg": pose_rms_deg(commanded).tolist(),
            "commanded_by": {k: int(v) for k, v in zip(*np.unique(
                np.asarray(commanded_rec.array("commanded_by"), str), return_counts=True),
                strict=True)},
            "estimate_rms_deg": angles["rms_error_deg"],
            "onnx_train_length_rms_mm": length_rms_mm(
                onnx_lengths(onnx, tr.theta, tr.tension), tr.length),
        }
        results["geometric"]["estimate_rms_deg"] = angles["geometric_rms_error_deg"]
    results["schemas"] = dict(sorted(results["schemas"].items(), key=lambda kv: int(kv[0])))
    saved.write_text(json.dumps(results, indent=2) + "\n")
    print(table(results, rec.joints))


def table(r: dict, joints: list[str]) -> str:
    def deg(v: list[float]) -> str:
        return " / ".join(f"{x:.2g}" if x < 0.1 else f"{x:.2f}" for x in v)

    g = r["geometric"]
    lines = [f"conceal: {', '.join(r['conceal'])}; {r['test_samples']} new poses",
             f"| commanded / estimated by | length error, new poses [mm rms] | pose error "
             f"[° rms, {' / '.join(joints)}] | joint-angle estimate [° rms] |",
             "|---|---|---|---|",
             f"| geometric model | {g['length_rms_mm']:.3f} | {deg(g['pose_rms_deg'])} | "
             f"{deg(g['estimate_rms_deg'])} |"]
    for s in r["schemas"].values():
        ratio = np.asarray(g["pose_rms_deg"]) / np.asarray(s["pose_rms_deg"])
        by = s.get("commanded_by", {"schema": s.get("commanded_by_schema")})
        lines.append(f"| schema, {s['n_train']} samples ({s['epochs']} epochs, "
                     f"{s['structure']}) | {s['length_rms_mm']:.3f} | "
                     f"{deg(s['pose_rms_deg'])} ({' / '.join(f'{x:.1f}×' for x in ratio)} "
                     f"better; {', '.join(f'{v} {k}' for k, v in by.items())}) | "
                     f"{deg(s['estimate_rms_deg'])} |")
    lines.append("ONNX length vs recorded, own training rows [mm rms]: " + ", ".join(
        f"n={n}: {s['onnx_train_length_rms_mm']:.3f}" for n, s in r["schemas"].items()))
    return "\n".join(lines)


if __name__ == "__main__":
    main()
