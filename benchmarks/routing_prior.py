"""The robot description as prior on an arm whose routing differs from it (the README's
"With the robot description as prior" paragraph).

A recording simulated with every via point moved by a random 4 mm (`pimbs simulate
--samples 120 --seed 3 --conceal routing:0.004`), trained with `pimbs train`'s defaults on
100 rows (the other 20 evaluate); then the same with tendon friction μ = 0.1 concealed as
well, with the default loss and without the physics term (`--loss basic+const`). Prints the
learned and the description's rms length error on the evaluation rows and the torque noise
`pimbs train` estimated. Minutes of CPU (three trainings of 5000 epochs on one thread).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/routing_prior.py            # the numbers
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/routing_prior.py --readme   # the block
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ROUTING = ["--conceal", "routing:0.004"]
FRICTION = ["--conceal", "tendon_friction:0.1"]


def _pimbs(*args: str) -> None:
    run = subprocess.run([sys.executable, "-m", "pimbs_cli.main", *args], cwd=ROOT,
                         capture_output=True, text=True, check=False)
    if run.returncode != 0:
        raise SystemExit(f"pimbs {' '.join(args)} failed (exit {run.returncode}): "
                         f"{run.stderr.strip()[-400:]}")


def train(data: Path, work: Path, epochs: int, *extra: str) -> dict:
    """`pimbs train DATA --n-train 100 --epochs E --threads 1 [extra]`'s metrics."""
    out = work / f"{data.stem}{''.join(extra).replace('+', '-')}.json"
    _pimbs("train", str(data), "--n-train", "100", "--epochs", str(epochs), "--threads", "1",
           "--json", str(out), "--force", *extra)
    return json.loads(out.read_text())


def measure(work: Path, epochs: int) -> dict[str, dict]:
    clean, friction = work / "r120.parquet", work / "r120-friction.parquet"
    for path, conceal in ((clean, ROUTING), (friction, ROUTING + FRICTION)):
        _pimbs("simulate", "--samples", "120", "--seed", "3", *conceal, "--out", str(path),
               "--force")
    return {"routing": train(clean, work, epochs),
            "friction": train(friction, work, epochs),
            "friction_basic_const": train(friction, work, epochs, "--loss", "basic+const")}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epochs", type=int, default=5000)
    ap.add_argument("--readme", action="store_true", help="print the README block")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        m = measure(Path(tmp), args.epochs)
    r, f, b = m["routing"], m["friction"], m["friction_basic_const"]
    if not args.readme:
        for name, metrics in m.items():
            print(f"{name}: learned {metrics['eval_rms_mm']:.3f} mm rms, description's model "
                  f"{metrics['model_rms_mm']:.3f} mm, torque noise "
                  f"{metrics['torque_noise_rms']:.3g} N·m")
        return 0
    print(f"**With the robot description as prior** (a recording simulated with every via "
          f"point moved\nby a random 4 mm, `pimbs simulate --samples 120 --seed 3 --conceal "
          f"routing:0.004`, then\n`pimbs train r120.parquet --n-train 100 --epochs "
          f"{args.epochs} --threads 1`; the other 20 rows\nevaluate; `OMP_NUM_THREADS=1 "
          f".venv/bin/python benchmarks/routing_prior.py`): learned\n"
          f"**{r['eval_rms_mm']:.3f} mm** rms against **{r['model_rms_mm']:.2f} mm** for the "
          f"description's model on the\nsame poses. With friction μ = 0.1 concealed as well "
          f"(`--conceal routing:0.004 --conceal\ntendon_friction:0.1`, same command): learned "
          f"{f['eval_rms_mm']:.3f} mm, without PINN (`--loss\nbasic+const`) "
          f"{b['eval_rms_mm']:.3f} mm, the description's model {f['model_rms_mm']:.2f} mm; "
          f"`pimbs train`\nput the torque balance at ±{f['torque_noise_rms']:.3g} N·m "
          f"(±{r['torque_noise_rms']:.3g} N·m without friction), the floor\nunder which the "
          f"physics weight backs off.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
