"""Collections that finish on arms written by others: floors an arm with unequal antagonist
levers can hold, holdings the arm stays in, plants equal to their description, timesteps fit
for the elastic elements, and runs that say honestly how they ended."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pimbs_arm.holding import _Stiffness, held_muscles, holdable
from pimbs_arm.model import ArmModel, sample_poses
from pimbs_arm.poses import FLOOR_SCALES, PLAN_CEILING, feasible, plan_poses
from pimbs_cli.main import main
from pimbs_hw.collection.plan import CollectionPlan
from pimbs_hw.collection.progress import summary_lines
from pimbs_hw.collection.relax import relax_fall
from pimbs_hw.collection.routine import Summary
from pimbs_recording.format import read_recording

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
ARMS = FIXTURES / "mujoco"
LEVER = ARMS / "lever_3dof.xml"  # elbow flexor up to 67 mm, extensor on a 25 mm pulley
FINGER = FIXTURES / "myosuite" / "finger" / "myofinger_v0.xml"  # MyoSuite's, unchanged
ARM26 = ARMS / "arm26" / "arm26.muscles.yaml"
FAST = ["--mock-speed", "5", "--settle-window", "0.06"]


@pytest.fixture(scope="module")
def lever() -> ArmModel:
    return ArmModel.load(LEVER)


@pytest.fixture(scope="module")
def finger() -> ArmModel:
    return ArmModel.load(FINGER)


# ------------------------------------------------------------------ floors the arm can hold
def test_atl_floors_no_pose_holds_are_scaled_at_the_drawn_pose(lever):
    """The paper's floors draw a 250 N elbow flexor floor that no pose balances with the
    extensor on a third of its lever: the sample keeps its drawn pose and its drawn floors,
    scaled by the largest factor the arm holds there; other samples are today's draws."""
    plan = plan_poses(lever, 12, seed=0)
    assert plan.scaled, "the fixture's levers must make some floors unholdable"
    paper = np.random.default_rng([0, 1]).uniform(10, 300, (12, lever.n_muscles))
    drawn = sample_poses(lever.joint_range, 12, np.random.default_rng([0, 0]))
    for i in range(12):
        assert feasible(lever, plan.poses[i], plan.floors[i])
        if i in plan.scaled:
            scale = plan.drawn_floors[i] / paper[i]
            assert np.allclose(scale, scale[0]) and np.isclose(FLOOR_SCALES, scale[0]).any()
            assert not feasible(lever, plan.poses[i], np.maximum(paper[i], 10.0))
        else:
            np.testing.assert_array_equal(plan.drawn_floors[i], paper[i])
        if i not in plan.replaced:
            np.testing.assert_array_equal(plan.poses[i], drawn[i])
    again = plan_poses(lever, 12, seed=0)  # a function of the seed: simulate and collect agree
    np.testing.assert_array_equal(again.floors, plan.floors)
    assert again.scaled == plan.scaled


def test_simulate_and_the_plan_of_an_arm_with_unequal_levers(lever, tmp_path):
    out = tmp_path / "sim.parquet"
    res = CliRunner().invoke(main, ["simulate", "--robot", str(LEVER), "-n", "12", "--out",
                                    str(out)])
    assert res.exit_code == 0, res.output
    assert "sets of ATL tension floors cannot be held at any pose" in res.output
    rec = read_recording(out)
    plan = CollectionPlan(lever, 12, seed=0)
    assert rec.meta["scaled_floors"] == list(plan.scaled)
    np.testing.assert_array_equal(rec.theta_command, plan.poses)
    assert rec.tension.max() <= PLAN_CEILING * lever.f_max.max() + 3.0  # noise


def test_builtin_arms_draw_the_papers_floors_unscaled():
    for name in ("two-link-4-muscle", "left-arm-5dof"):
        arm = ArmModel.load(name)
        plan = plan_poses(arm, 100, seed=0)
        assert plan.scaled == () and plan.replaced == ()
        np.testing.assert_array_equal(
            plan.drawn_floors,
            np.random.default_rng([0, 1]).uniform(10, 300, (100, arm.n_muscles)))


# -------------------------------------------------------------- holdings the arm stays in
def test_finger_holdings_are_stable_where_the_greedy_choice_was_a_saddle(finger):
    """MyoSuite's finger: holding the four most useful tendons in length leaves some ATL
    poses a saddle of the static energy (the arm runs off them); the plan picks held muscles
    and approach tensions whose stiffness is positive definite, and the approach lengths,
    all length-controlled, rest at the pose (equal pretensions ran it to the joint limits)."""
    plan = CollectionPlan(finger, 10, seed=0)
    saddles = 0
    for i in range(10):
        t = plan.target(i)
        stiff = _Stiffness(finger, t.theta, t.tension, t.tension)
        greedy = held_muscles(finger.muscle_jacobian(t.theta), t.tension)
        saddles += stiff.smallest(1.0, greedy) < 0
        assert stiff.smallest(1.0, t.held) >= stiff.need > 0
        approach = finger.equilibrium("length", t.approach_length, theta0=t.theta)
        np.testing.assert_allclose(approach.theta, t.theta, atol=1e-6)
        uniform = finger.h_geom(t.theta) - finger.stretch(plan.pretension)
        drift = finger.equilibrium("length", uniform, theta0=t.theta).theta - t.theta
        assert np.abs(drift).max() > 0.05 or i  # equal pretensions do not hold sample 0
    assert saddles >= 2


def test_a_pose_no_holding_keeps_is_not_planned(finger):
    drawn = sample_poses(finger.joint_range, 10, np.random.default_rng([0, 0]))
    plan = plan_poses(finger, 10, seed=0)
    for i in plan.replaced:  # replaced: out of reach, or a saddle for every holding
        floor = plan.floors[i]
        try:
            tension = finger.tension_distribution(drawn[i], floor,
                                                  f_max=PLAN_CEILING * finger.f_max)
        except Exception:  # noqa: BLE001 - out of reach
            continue
        assert not holdable(finger, drawn[i], tension)


# ---------------------------------------------------- a plant equal to its description
@pytest.mark.parametrize("plant, map_kind", [(True, "al"), (True, "atl"), (False, "al")])
def test_collect_on_an_arm_equal_to_its_description_finishes(lever, tmp_path, plant,
                                                              map_kind):
    """The arm of another writer on MuJoCo's dynamics (its own MJCF as the plant) and on the
    built-in quasi-static arm: every pose held where the plan says, no wire above what the
    plan asks. Its elbow range leaves out θ = 0: the simulated arm powers up within its
    limits, not with the lengths of θ = 0, which stretch a wire by centimetres."""
    out = tmp_path / "c.parquet"
    args = ["collect", "--port", "virtual", "--robot", str(LEVER), "--samples", "2",
            "--seed", "1", "--map", map_kind, "--out", str(out), *FAST]
    res = CliRunner().invoke(main, args + (["--plant", str(LEVER)] if plant else []))
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.n_rows == 2
    plan = CollectionPlan(lever, 2, seed=1, map_kind=map_kind)
    asked = np.array([plan.target(i).tension for i in rec.sample])
    assert np.abs(rec.tension - asked).max() < 0.05 * lever.f_max.max()
    assert np.abs(rec.theta - rec.theta_command).max() < 0.01


def test_the_finger_on_itself_keeps_its_poses(tmp_path):
    out = tmp_path / "f.parquet"
    res = CliRunner().invoke(main, ["collect", "--port", "virtual", "--robot", str(FINGER),
                                    "--plant", str(FINGER), "--samples", "3", "--seed", "2",
                                    "--out", str(out), *FAST])
    assert res.exit_code == 0, res.output
    assert "integrated with 1 ms steps, not its file's 2 ms" in res.output
    rec = read_recording(out)
    assert rec.n_rows == 3 and np.abs(rec.theta - rec.theta_command).max() < 0.01


# ------------------------------------------------------------ relaxing, and how runs end
def test_a_relax_that_leaves_the_routed_range_is_named_and_the_arm_held(tmp_path):
    """MuJoCo's arm26 made two-sided ([0.2, 1.6] rad): relaxed, its shoulder turns to its
    stop at 120 degrees, where its extensors have flipped sides. The collection says so
    before the arm is touched and holds the arm instead."""
    fall = relax_fall(ArmModel.load(ARM26))
    assert fall is not None and "shoulder would turn to 2.094 rad (its hard stop)" in fall
    assert relax_fall(ArmModel.load("two-link-4-muscle")) is None
    out = tmp_path / "a.parquet"
    res = CliRunner().invoke(main, ["collect", "--port", "virtual", "--robot", str(ARM26),
                                    "--plant", str(ARMS / "arm26" / "arm26_damped.xml"),
                                    "--samples", "3", "--out", str(out), *FAST])
    assert res.exit_code == 0, res.output
    assert f"note: {fall}; the collection holds the simulated arm" in res.output
    rec = read_recording(out)
    assert rec.n_rows == 3 and np.abs(rec.theta - rec.theta_command).max() < 0.02


def test_a_run_that_kept_nothing_is_not_complete():
    s = Summary(path="x.parquet", total=10, start=0, next_sample=10, skipped=list(range(10)))
    assert not s.complete and s.failed == "no pose was recorded: all 10 tried were given up"
    assert summary_lines(s)[0].startswith("collection FAILED: no pose was recorded")
    s = Summary(path="x.parquet", total=10, start=0, next_sample=10, written=3,
                skipped=list(range(7)))
    assert not s.complete and "7 of the 10 poses tried were given up" in s.failed
    s = Summary(path="x.parquet", total=10, start=0, next_sample=10, written=9, skipped=[4])
    assert s.complete and s.failed is None
