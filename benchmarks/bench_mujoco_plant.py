"""How much faster than real time the MuJoCo plant runs, for a 10-muscle arm on one core.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_mujoco_plant.py [--links 5] [--seconds 20]

Writes a planar chain of LINKS hinges (each with a cylinder pulley and a flexor/extensor
pair wrapping it: 2·LINKS spatial tendons, 10 for the default) as a bare MJCF, loads it as the
description, and drives ``MujocoPlant`` (the mock bus's MuJoCo arm) through a new pose every
second of arm time (length commands from the description's equilibrium, ramped over 0.2 s as
the collection does), stepping it in 10 ms calls as the mock bus does. Prints arm seconds
simulated per wall second (> 1: faster than real time) and the MuJoCo timestep, with the
pose error at the end of each second as a check that the arm is really moving and settling.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pimbs_arm.model import ArmModel  # noqa: E402
from pimbs_hw.mock.mujoco_plant import MujocoPlant  # noqa: E402


def chain_mjcf(links: int, length: float = 0.15, mass: float = 0.3) -> str:
    """A planar chain of ``links`` hinges about y, each wrapped by two antagonist tendons."""
    bodies, tendons, close = [], [], []
    for i in range(links):
        pos = "0 0 0" if i == 0 else f"0 0 {-length}"
        parent_sites = "" if i else (
            '<site name="o_f0" pos="-0.018 0 0.08"/><site name="o_b0" pos="0.018 0 0.08"/>'
            '<site name="s_f0" pos="-0.08 0 0"/><site name="s_b0" pos="0.08 0 0"/>')
        nxt = (f'<site name="o_f{i + 1}" pos="-0.016 0 {-length + 0.06}"/>'
               f'<site name="o_b{i + 1}" pos="0.016 0 {-length + 0.06}"/>'
               f'<site name="s_f{i + 1}" pos="-0.07 0 {-length}"/>'
               f'<site name="s_b{i + 1}" pos="0.07 0 {-length}"/>') if i + 1 < links else ""
        bodies.append(
            f'{parent_sites}<body name="link{i}" pos="{pos}">'
            f'<joint name="j{i}" type="hinge" axis="0 1 0" range="-0.4 0.4" damping="0.5" '
            f'armature="0.002"/>'
            f'<inertial pos="0 0 {-length / 2}" mass="{mass}" diaginertia="1e-3 1e-3 1e-4"/>'
            f'<geom name="pulley{i}" type="cylinder" size="0.022 0.01" zaxis="0 1 0" '
            f'contype="0" conaffinity="0"/>'
            f'<site name="i_f{i}" pos="-0.016 0 -0.06"/><site name="i_b{i}" pos="0.016 0 -0.06"/>'
            f'{nxt}')
        close.append("</body>")
        for side in ("f", "b"):
            tendons.append(f'<spatial name="{"flexor" if side == "f" else "extensor"}{i}">'
                           f'<site site="o_{side}{i}"/>'
                           f'<geom geom="pulley{i}" sidesite="s_{side}{i}"/>'
                           f'<site site="i_{side}{i}"/></spatial>')
    return (f'<mujoco model="chain-{links}"><option timestep="0.001"/><worldbody>'
            f'{"".join(bodies)}{"".join(reversed(close))}</worldbody>'
            f'<tendon>{"".join(tendons)}</tendon></mujoco>')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--links", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=20.0, help="arm time to simulate")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        xml = Path(tmp) / "chain.xml"
        xml.write_text(chain_mjcf(args.links))
        arm = ArmModel.load(xml)
        plant = MujocoPlant(xml, arm)
        rng = np.random.default_rng(args.seed)
        modes = ("length",) * arm.n_muscles
        previous = plant.state.length.copy()
        wall, arm_s, errors = 0.0, 0.0, []
        while arm_s < args.seconds:
            target = rng.uniform(0.6 * arm.joint_range[:, 0], 0.6 * arm.joint_range[:, 1])
            goal = arm.length(target, arm.tension_distribution(target, 40.0))
            start = time.perf_counter()
            for k in range(100):  # one arm second in 10 ms calls; 0.2 s ramp to the goal
                plant.command(modes, previous + min(1.0, (k + 1) / 20) * (goal - previous))
                plant.step(0.01)
            wall += time.perf_counter() - start
            arm_s += 1.0
            previous = goal
            errors.append(np.abs(plant.state.theta - target).max())
    print(f"{arm.n_muscles} muscles, {arm.n_joints} joints, MuJoCo timestep "
          f"{plant.mj.opt.timestep * 1e3:g} ms: {arm_s:.0f} s of arm time in {wall:.2f} s "
          f"wall = {arm_s / wall:.1f}x real time")
    print(f"pose error after each second: median {np.median(errors):.2e} rad, "
          f"max {np.max(errors):.2e} rad")


if __name__ == "__main__":
    main()
