"""Only feasible poses: the plan shared by simulate and collect, and a foreign arm end to end
(simulate -> mock-bus collect -> diagnose) without editing its URDF."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pimbs_arm.model import ArmModel, InfeasiblePoseError, sample_poses
from pimbs_arm.poses import PLAN_CEILING, feasible, plan_poses
from pimbs_cli.main import main
from pimbs_hw.collection.plan import CollectionPlan
from pimbs_hw.collection.session import stop_advice
from pimbs_hw.safety import TensionLimit
from pimbs_recording.format import read_recording
from pimbs_sim.simulate import simulate

ACME = Path(__file__).resolve().parents[1] / "fixtures" / "foreign_arm" / \
    "acme_left_arm.muscles.yaml"
FAST = ["--mock-speed", "20", "--settle-window", "0.06"]


@pytest.fixture(scope="module")
def acme() -> ArmModel:
    return ArmModel.load(ACME)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 6])
def test_every_planned_pose_is_held_within_f_max_and_only_infeasible_ones_change(acme, seed):
    plan = plan_poses(acme, 120, seed)
    drawn = sample_poses(acme.joint_range, 120, np.random.default_rng([seed, 0]))
    changed = np.flatnonzero((plan.poses != drawn).any(axis=1))
    assert changed.tolist() == list(plan.replaced)
    for i in range(120):
        tension = acme.tension_distribution(plan.poses[i], plan.floors[i],
                                            f_max=PLAN_CEILING * acme.f_max)
        assert tension.max() <= PLAN_CEILING * acme.f_max.max() + 1e-6
        assert (tension >= plan.floors[i] - 1e-6).all()
        if i in plan.replaced:  # the first draw could not be held, the replacement can
            assert not feasible(acme, drawn[i], plan.floors[i])
            assert (plan.poses[i] >= acme.joint_range[:, 0]).all()
            assert (plan.poses[i] <= acme.joint_range[:, 1]).all()
    again = plan_poses(acme, 120, seed)
    np.testing.assert_array_equal(again.poses, plan.poses)


def test_some_random_poses_of_the_foreign_arm_were_infeasible(acme):
    # the fixture's f_max is below what some ATL draws need: the replacement is exercised
    replaced = sum(len(plan_poses(acme, 120, s).replaced) for s in range(4))
    assert 5 <= replaced <= 100


def test_simulate_and_collect_plan_the_same_poses_and_no_tension_above_f_max(acme):
    plan = CollectionPlan(acme, 60, seed=2)
    data, meta = simulate(acme, 60, "atl", seed=2, noise=0.0)
    np.testing.assert_array_equal(plan.poses, data["theta_command"])
    assert meta["replaced_poses"] == list(plan.replaced) and plan.replaced
    assert data["tension"].max() <= acme.f_max.max()
    # without the plan, the same seed asks some wire for more than the plan allows
    raw = sample_poses(acme.joint_range, 60, np.random.default_rng([2, 0]))
    floors = np.random.default_rng([2, 1]).uniform(10, 300, (60, acme.n_muscles))
    worst = 0.0
    for theta, floor in zip(raw, floors, strict=True):
        try:
            worst = max(worst, acme.tension_distribution(theta, floor).max())
        except InfeasiblePoseError:
            worst = np.inf
    assert worst > PLAN_CEILING * acme.f_max.max()


def test_builtin_robots_keep_their_seeded_poses():
    for name in ("two-link-4-muscle", "left-arm-5dof"):
        arm = ArmModel.load(name)
        plan = plan_poses(arm, 150, 0)
        assert plan.replaced == ()
        np.testing.assert_array_equal(
            plan.poses, sample_poses(arm.joint_range, 150, np.random.default_rng([0, 0])))


def test_foreign_arm_simulates_collects_on_the_mock_bus_and_is_diagnosed(tmp_path):
    """The ACME arm as shipped: a seed whose plan replaced poses collects to the end, and the
    diagnosis names a concealed elbow encoder offset against the simulated reference."""
    n, seed = 40, 6
    ref, real = tmp_path / "sim.parquet", tmp_path / "real.parquet"
    res = CliRunner().invoke(main, ["simulate", "--robot", str(ACME), "--samples", n,
                                    "--seed", seed, "--out", str(ref)])
    assert res.exit_code == 0, res.output
    assert "4 of 40 drawn poses" in res.output and "replaced" in res.output
    args = ["collect", "--port", "virtual", "--robot", str(ACME), "--samples", n, "--seed",
            seed, "--out", str(real), *FAST, "--conceal", "joint_offset:0.04,joints=l_elbow_pitch"]
    res = CliRunner().invoke(main, args)
    for _ in range(5):  # the simulated boards share this (loaded) CPU: a starved board may
        if res.exit_code == 0:  # stop the run; --resume must then get further every time
            break
        assert "WatchdogExpired" in res.output or "BoardSilent" in res.output, res.output
        rows = read_recording(real).n_rows
        res = CliRunner().invoke(main, [*args, "--resume"])
        assert res.exit_code == 0 or read_recording(real).n_rows > rows, res.output
    assert res.exit_code == 0, res.output
    rec = read_recording(real)
    assert rec.n_rows == n and rec.tension.max() < ArmModel.load(ACME).f_max.max()
    np.testing.assert_array_equal(rec.theta_command, read_recording(ref).theta_command)
    res = CliRunner().invoke(main, ["diagnose", str(real), "--reference", str(ref),
                                    "--robot", str(ACME)])
    assert res.exit_code == 0, res.output
    named = res.output.split("Missing physics")[1]
    assert "1. joint_offset (l_elbow_pitch)" in named


def test_ceiling_stop_names_the_pose_and_whether_the_plan_needed_it(acme):
    plan = CollectionPlan(acme, 5, seed=1)
    stop = TensionLimit("board tension ceiling reached; the board relaxed", muscle="el_flexor",
                        board_id=15, port="virtual")
    text = stop_advice(stop, plan, 3)
    pose = f"l_elbow_pitch={plan.poses[3][2]:.3f}"
    assert "sample 3" in text and pose in text and "el_flexor" in text
    assert "did not need that tension" in text and "snag" in text and "--resume" in text
    # a simulated arm warned as barely damped: its own swing, not a snag, took the wire there
    rings = stop_advice(stop, plan, 3, rings="warning: the plant arm.xml is barely damped")
    assert "barely damped" in rings and "damping" in rings and "snag" not in rings
    weak = copy.copy(acme)
    weak.f_max = np.full(acme.n_muscles, 1.0)  # a wire that cannot carry what the plan asks
    plan.model = weak
    text = stop_advice(stop, plan, 3)
    assert "needed that tension (an infeasible pose)" in text and "pimbs robot" in text


def test_atl_floors_of_an_arm_with_a_weak_muscle_stay_within_its_reach(tmp_path):
    """An arm with a muscle too weak for the paper's 300 N floors draws every floor up to 3/4
    of that muscle's f_max (an antagonist's floor is load on it), and says so in the
    recording; an arm whose muscles are strong enough keeps the paper's draws exactly."""
    import yaml

    robots = Path(__file__).resolve().parents[1] / "calibration" / "robots"
    spec = yaml.safe_load((robots / "two-link-4-muscle.muscles.yaml").read_text())
    spec["urdf"] = str(robots / spec["urdf"])
    spec["muscles"][1]["f_max"] = 200.0  # the shoulder extensor: a 300 N floor is beyond it
    path = tmp_path / "weak.muscles.yaml"
    path.write_text(yaml.safe_dump(spec))
    weak = ArmModel.load(path)
    plan = plan_poses(weak, 300, seed=4)
    paper = np.random.default_rng([4, 1]).uniform(10, 300, (300, 4))
    np.testing.assert_allclose(plan.drawn_floors, 10 + (paper - 10) * 140 / 290, rtol=1e-12)
    assert plan.replaced == ()  # every draw can be held, none replaced
    data, meta = simulate(weak, 50, "atl", seed=4, noise=0.0)
    assert meta["f_min"] == [10.0, 150.0] and data["tension"][:, 1].max() <= 0.9 * 200
    strong = ArmModel.load("two-link-4-muscle")
    np.testing.assert_array_equal(plan_poses(strong, 300, seed=4).drawn_floors, paper)
    assert simulate(strong, 5, "atl", seed=4, noise=0.0)[1]["f_min"] == [10.0, 300.0]
