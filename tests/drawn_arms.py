"""Arms of the diagnosis population, recorded as its benchmark records them.

A test that rebuilds one drawn arm's narrow session (and, where the diagnosis proposes
poses, the session that collects them) checks the diagnosis on exactly the recording the
population measured, without the population's files.
"""

from __future__ import annotations

from pathlib import Path

from pimbs_recording.format import write_recording
from pimbs_sim.simulate import simulate


def drawn_narrow_pair(tmp_path: Path, seed: int, effects: list[str], family: str = "mujoco"):
    """A population arm's narrow session on PIMBS' simulator (the arm drawn as ``family``
    draws it): (arm's description, real recording, reference, the drawn conditions), the
    concealed effects checked."""
    import benchmarks.population_diagnosis as bench
    from pimbs_sim.conditions import draw_conditions
    from pimbs_sim.population import make_arm

    spec = make_arm(seed, family, tmp_path / "arm")
    truth = draw_conditions(spec, "ours")
    assert [e["name"] for e in truth.effects] == effects
    noise_seed = seed + bench.NARROW_SEED
    plan = bench.narrow_plan({"description": spec.description, "seed": seed}, tmp_path)
    real, ref = _session(tmp_path, "narrow", spec.description, truth, noise_seed, plan,
                         "al")
    return spec.description, real, ref, truth


def collect_poses(tmp_path: Path, description: Path, truth, seed: int, csv: str
                  ) -> tuple[Path, Path]:
    """The session that collects a poses file (``csv``, as ``--poses-out`` writes it) on
    the same drawn arm, effects and sensors, with its clean reference: (real, reference)."""
    import benchmarks.population_diagnosis as bench
    from pimbs_arm.model import ArmModel
    from pimbs_arm.poses_file import read_pose_plan

    tmp_path.mkdir(parents=True, exist_ok=True)
    design = tmp_path / "poses.csv"
    design.write_text(csv)
    plan = read_pose_plan(design, ArmModel.load(description))
    return _session(tmp_path, "settle", description, truth, seed + bench.SETTLE_SEED, plan,
                    "atl")


def _session(tmp_path: Path, stem: str, description: Path, truth, noise_seed: int, plan,
             map_kind: str) -> tuple[Path, Path]:
    """(real, reference) of ``plan`` on the drawn arm: the real one with the drawn effects,
    sensors and noise, the reference clean with noise of its own, as the benchmark pairs
    them."""
    import benchmarks.population_diagnosis as bench
    from pimbs_arm.model import ArmModel

    arm = ArmModel.load(description)
    paths = []
    for name, kwargs in (("sim", {"noise_seed": noise_seed + bench.REFERENCE_NOISE}),
                         ("real", {"effects": truth.sim_effects(), "sensors": truth.sensors,
                                   "noise": truth.noise})):
        data, meta = simulate(arm, len(plan.poses), map_kind, seed=noise_seed, poses=plan,
                              **kwargs)
        paths.append(tmp_path / f"{stem}.{name}.parquet")
        write_recording(paths[-1], data, meta)
    return paths[1], paths[0]
