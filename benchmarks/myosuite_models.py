"""MyoSuite's models as shipped: what PIMBS makes of each, and its couplings against MuJoCo's.

Fetches nothing: point it at a checkout of MyoSuite's models (https://github.com/MyoHub/myo_sim)

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/myosuite_models.py --myo-sim ~/src/myo_sim

1. **Couplings.** Every model with ``<equality><joint>`` couplings (the arm: 11, the legs: 14,
   the torso and body more): at the joint ranges' corners-of-a-box (lower and upper bound of
   every driven joint) and seeded random poses, PIMBS's muscle lengths, Jacobian (with respect
   to the driven joints) and gravity against MuJoCo's with the coupling *MuJoCo enforces*:
   the followers solved from MuJoCo's own equality residual (``efc_pos``/``efc_J``,
   ``tests/mujoco_truth.py``), never from PIMBS's reading of ``polycoef``. Prints the largest
   differences; exits 1 if the arm or the legs differ by more than 1e-9.
2. **Every model MuJoCo loads stand-alone** (each ``*.xml`` outside ``assets/``): ``pimbs
   robot MODEL`` and ``pimbs simulate --robot MODEL --samples 5``, run as a user runs them;
   per model: works, or the one line the command ended with. ``--quick`` skips the
   simulations.
3. **A short collection on the model itself** (every model ``simulate`` accepts, with the map
   it accepted): ``pimbs collect --port virtual --robot MODEL --plant PLANT --samples 5`` on
   the simulated boards with MuJoCo integrating the plant, first the model itself as the
   plant, then the model with every tendon path site moved 1 mm in a seeded direction (a
   real arm always differs from its description by millimetres): rows kept of those
   planned, or the one line the collection stopped with. A stop fails the benchmark where
   the plant is the model itself.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pimbs_arm.model import ArmModel  # noqa: E402
from pimbs_calibration.description import DescriptionError, load_robot  # noqa: E402
from pimbs_calibration.mjcf import MjcfError, compile_model, joint_couplings  # noqa: E402
from tests.mujoco_truth import coupled_truth  # noqa: E402

MUST_AGREE = ("arm/myoarm.xml", "leg/myolegs.xml")
ONE_BUS = "so one bus carries no such board"  # more muscles than one bus has board ids
TOLERANCE = 1e-9


def models(myo_sim: Path) -> list[Path]:
    """Every MJCF of the checkout that is a model of its own (not under ``assets/``)."""
    return sorted(p for p in myo_sim.rglob("*.xml")
                  if "assets" not in p.relative_to(myo_sim).parts)


def coupling_differences(xml: Path, n_random: int, seed: int = 0) -> dict[str, float]:
    """Largest |PIMBS - MuJoCo enforced| of lengths (m), Jacobian (m/rad) and gravity (N·m)
    over the box corners of the driven joints' ranges and ``n_random`` seeded poses."""
    robot = load_robot(xml)
    arm = ArmModel(robot, check=False)
    lo, hi = arm.joint_range.T
    poses = [lo, hi, *np.random.default_rng(seed).uniform(lo, hi, (n_random, arm.n_joints))]
    worst = {"length": 0.0, "jacobian": 0.0, "gravity": 0.0, "residual": 0.0}
    for theta in poses:
        truth = coupled_truth(arm.backend.mj_model, arm.joints, arm.muscles, theta,
                              held=dict(robot.locked))
        kin = arm.backend.kinematics(theta)
        worst["length"] = max(worst["length"], float(np.abs(kin.length - truth.length).max()))
        worst["jacobian"] = max(worst["jacobian"],
                                float(np.abs(kin.jacobian - truth.jacobian).max()))
        worst["gravity"] = max(worst["gravity"],
                               float(np.abs(arm.gravity_torque(theta) - truth.gravity).max()))
        worst["residual"] = max(worst["residual"], truth.residual)
    worst.update(poses=len(poses), joints=arm.n_joints, followers=len(robot.couplings),
                 muscles=arm.n_muscles)
    return worst


def ignoring_couplings(xml: Path, n_random: int, seed: int = 0) -> float:
    """Largest length difference (m) had the followers been left at their reference pose
    (what a model that ignores the couplings measures), for scale."""
    robot = load_robot(xml)
    arm = ArmModel(robot, check=False)
    uncoupled = ArmModel(dataclasses.replace(robot, couplings=()), check=False)
    lo, hi = arm.joint_range.T
    return max(float(np.abs(arm.backend.kinematics(t).length
                            - uncoupled.backend.kinematics(t).length).max())
               for t in np.random.default_rng(seed).uniform(lo, hi, (n_random, arm.n_joints)))


def facts(xml: Path) -> str:
    """Joints, tendons and joint equalities as MuJoCo compiles the file."""
    try:
        m = compile_model(xml)
    except MjcfError:
        return "-"
    active = sum(c.active for c in joint_couplings(m))
    return f"{m.njnt} joints, {m.ntendon} tendons, {active} joint equalities"


def run_pimbs(args: list[str], timeout_s: float) -> tuple[bool, str, float]:
    """Run ``pimbs ARGS`` as a user does; (worked, its last line, seconds)."""
    exe = Path(sys.executable).with_name("pimbs")
    start = time.perf_counter()
    try:
        res = subprocess.run([str(exe), *args], capture_output=True, text=True,
                             timeout=timeout_s, env={**os.environ, "OMP_NUM_THREADS": "1"})
    except subprocess.TimeoutExpired:
        return False, f"(no answer within {timeout_s:g} s)", timeout_s
    lines = (res.stdout + res.stderr).strip().splitlines()
    last = lines[-1] if lines else ""
    if "Traceback" in res.stderr:
        last = "TRACEBACK: " + last
    return res.returncode == 0, last, time.perf_counter() - start


def simulate(xml: Path, tmp: Path, timeout_s: float) -> tuple[str, str | None]:
    """``pimbs simulate --samples 5`` (ATL-Map, the default): works, or its last line; where
    the ATL-Map fails but the robot itself is usable, also the AL-Map's outcome. Second: the
    map that worked (None: neither)."""
    out = tmp / (xml.stem + ".parquet")
    base = ["simulate", "--robot", str(xml), "--samples", "5", "--out", str(out), "--force"]
    ok, said, took = run_pimbs(base, timeout_s)
    if ok:
        return f"works ({took:.0f} s)", "atl"
    if "cannot be turned both ways" in said or "field '" in said:
        return said, None  # the description itself: the AL-Map says the same
    ok_al, said_al, took_al = run_pimbs([*base, "--map", "al"], timeout_s)
    return (f"{said} [--map al: {f'works ({took_al:.0f} s)' if ok_al else said_al}]",
            "al" if ok_al else None)


def moved_plant(xml: Path, shift_m: float = 1e-3, seed: int = 0) -> Path:
    """The model with every tendon path site moved ``shift_m`` in a seeded direction, written
    beside it (so its includes and meshes resolve as the model's do)."""
    import mujoco

    spec = mujoco.MjSpec.from_file(str(xml))
    model = spec.compile()
    names = sorted({mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_SITE, int(i))
                    for t, i in zip(model.wrap_type, model.wrap_objid, strict=True)
                    if t == mujoco.mjtWrap.mjWRAP_SITE} - {None})
    rng = np.random.default_rng(seed)
    for name in names:
        direction = rng.normal(size=3)
        site = spec.site(name)
        site.pos = np.asarray(site.pos) + shift_m * direction / np.linalg.norm(direction)
    out = xml.with_name(f"{xml.stem}.plant-1mm.xml")
    out.write_text(spec.to_xml())
    return out


def collect(xml: Path, plant: Path, map_kind: str, samples: int, tmp: Path,
            timeout_s: float) -> tuple[bool, str]:
    """``pimbs collect`` of ``samples`` poses of ``xml`` on the simulated boards, MuJoCo
    integrating ``plant``: (finished without a stop, "K of N rows (s)" or its last line)."""
    import pyarrow.parquet as pq

    out = tmp / f"{plant.stem}.collect.parquet"
    out.unlink(missing_ok=True)
    ok, said, took = run_pimbs(["collect", "--port", "virtual", "--robot", str(xml), "--plant",
                                str(plant), "--samples", str(samples), "--map", map_kind,
                                "--out", str(out)], timeout_s)
    if not ok:
        return False, said
    rows = pq.read_metadata(out).num_rows if out.is_file() else 0
    return True, f"{rows} of {samples} rows ({took:.0f} s)"


def _cell(text: str, width: int = 500) -> str:
    """A table cell: the line, its middle cut where it is very long (a list of 290 floors)."""
    return text if len(text) <= width else f"{text[:width - 120]} … {text[-110:]}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--myo-sim", type=Path, required=True,
                        help="a checkout of https://github.com/MyoHub/myo_sim")
    parser.add_argument("--poses", type=int, default=50,
                        help="random poses per coupled model (besides the range bounds)")
    parser.add_argument("--quick", action="store_true", help="no simulate or collect runs")
    parser.add_argument("--samples", type=int, default=5, help="poses per short collection")
    parser.add_argument("--only", nargs="*", help="only these models (paths in the checkout)")
    parser.add_argument("--timeout", type=float, default=600.0, help="s per command")
    args = parser.parse_args()
    root = args.myo_sim.expanduser().resolve()
    if not (root / "arm" / "myoarm.xml").is_file():
        parser.error(f"{root} is not a checkout of myo_sim (no arm/myoarm.xml)")
    failed = False

    print(f"## Couplings: PIMBS vs MuJoCo's enforced coupling ({root})\n")
    print("| model | driven joints | followers | muscles | poses | length [m] | Jacobian "
          "[m/rad] | gravity [N·m] | MuJoCo residual | followers ignored: length |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for xml in models(root):
        rel = str(xml.relative_to(root))
        try:
            m = compile_model(xml)
        except MjcfError:
            continue
        if not any(c.active for c in joint_couplings(m)):
            continue
        try:
            d = coupling_differences(xml, args.poses)
        except DescriptionError as exc:
            print(f"| {rel} | {exc} |")
            failed |= rel in MUST_AGREE
            continue
        off = ignoring_couplings(xml, min(args.poses, 20))
        print(f"| {rel} | {d['joints']} | {d['followers']} | {d['muscles']} | {d['poses']} | "
              f"{d['length']:.1e} | {d['jacobian']:.1e} | {d['gravity']:.1e} | "
              f"{d['residual']:.1e} | {off * 1e3:.0f} mm |")
        if rel in MUST_AGREE and max(d["length"], d["jacobian"], d["gravity"]) > TOLERANCE:
            failed = True

    print(f"\n## Every model: `pimbs robot`, `pimbs simulate --samples 5`, and "
          f"`pimbs collect --samples {args.samples} --plant` on itself and 1 mm off\n")
    print("| model | MuJoCo compiles | robot | simulate | collect, plant = model | "
          "collect, plant 1 mm off |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "myo_sim"  # the moved plants are written beside their models
        shutil.copytree(root, copy, ignore=shutil.ignore_patterns(".git"))
        for xml in models(copy):
            rel = str(xml.relative_to(copy))
            if args.only and rel not in args.only:
                continue
            ok, said, took = run_pimbs(["robot", str(xml)], args.timeout)
            robot = f"works ({took:.0f} s)" if ok else said
            sim, map_kind = ("-", None) if args.quick else simulate(xml, Path(tmp),
                                                                    args.timeout)
            same = moved = "-"
            if map_kind:
                ok_same, same = collect(xml, xml, map_kind, args.samples, Path(tmp),
                                        args.timeout)
                _, moved = collect(xml, moved_plant(xml), map_kind, args.samples, Path(tmp),
                                   args.timeout)
                failed |= not ok_same and ONE_BUS not in same  # refused before it starts
            print(f"| {rel} | {facts(xml)} | {_cell(robot)} | {_cell(sim)} | {_cell(same)} | "
                  f"{_cell(moved)} |".replace(str(copy) + "/", "").replace(tmp + "/", ""))
            failed |= any("TRACEBACK" in c for c in (robot, sim, same, moved))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
