"""`pimbs collect --schema`: poses commanded with a learned body schema, safely.

The schema here is the true arm itself (the concealed routing, behind the body-schema API):
what a perfectly learned schema would say. Learned schemas are measured by the benchmark.
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_cli.main import main
from pimbs_hw.collection.move import MoveConfig
from pimbs_hw.collection.plan import MAX_POSE_EXCURSION, CollectionPlan
from pimbs_hw.collection.resume import collection_meta, open_recording
from pimbs_hw.collection.routine import Collector
from pimbs_hw.collection.schema_plan import SchemaPlan
from pimbs_hw.collection.session import open_link
from pimbs_hw.collection.settle import SettleConfig
from pimbs_hw.safety import SafetyStop
from pimbs_learn.domain import Domain
from pimbs_learn.estimate import GeometricSchema
from pimbs_recording.format import read_recording
from pimbs_sim.effects import World, parse_effect
from tests.schema_models import small_model

ROUTING = "routing:0.004,seed=3"
WIDE = Domain(np.tile([-0.6, 0.6], (2, 1)), np.tile([0.0, 600.0], (4, 1)))


class ArmSchema(GeometricSchema):
    """An arm model as a body schema with a training domain, shifted by ``offset`` (m)."""

    def __init__(self, arm: ArmModel, domain: Domain = WIDE, offset: float = 0.0) -> None:
        super().__init__(arm)
        self.domain, self.offset = domain, offset

    def length(self, theta, f=None):
        return super().length(theta, f) + self.offset


@pytest.fixture(scope="module")
def model() -> ArmModel:
    return ArmModel.load("two-link-4-muscle")


@pytest.fixture(scope="module")
def true_arm(model) -> ArmModel:
    return World(model, (parse_effect(ROUTING),)).arm


def test_schema_plan_uses_the_schemas_G_and_lengths(model, true_arm):
    plan = SchemaPlan(model, ArmSchema(true_arm), 4, seed=4)
    geometric = CollectionPlan(model, 4, seed=4)
    for i in range(4):
        t, g = plan.target(i), geometric.target(i)
        assert t.commanded_by == "schema" and not t.note
        np.testing.assert_array_equal(t.theta, g.theta)
        G = true_arm.muscle_jacobian(t.theta)
        # the torque balance with the schema's moment arms, and the schema's lengths held
        np.testing.assert_allclose(-G.T @ t.tension, model.gravity_torque(t.theta), atol=1e-8)
        assert (t.tension >= t.f_min - 1e-8).all()
        held = t.held
        np.testing.assert_allclose(t.hold_command[held],
                                   true_arm.length(t.theta, t.tension)[held], atol=1e-12)
        assert np.abs(t.hold_command[held] - g.hold_command[held]).max() > 2e-5  # not the model


def test_schema_is_anchored_a_little_beyond_its_range_and_unused_far_beyond(model, true_arm):
    """Just outside the trained θ range: the schema at the edge plus the model's change
    beyond (continuous, the schema's own values inside); far outside: the geometric plan."""
    plan = SchemaPlan(model, ArmSchema(true_arm), 1, seed=4)
    theta = plan.poses[0]
    edge = Domain(np.stack([theta - 0.3, theta - 0.05], axis=1), WIDE.tension)
    t = SchemaPlan(model, ArmSchema(true_arm, edge), 1, seed=4).target(0)
    assert t.commanded_by == "schema+geometric" and "nearest trained point" in t.note
    assert "shoulder_pitch" in t.note and "elbow_pitch" in t.note
    clipped = theta - 0.05 + 0.05 * 0.25  # the edge widened by the margin: 5 % of 0.25 rad
    want = (true_arm.length(clipped, t.tension) + model.length(theta, t.tension)
            - model.length(clipped, t.tension))
    np.testing.assert_allclose(t.hold_command[t.held], want[t.held], atol=1e-12)
    g = CollectionPlan(model, 2, seed=4).target(0)
    narrow = Domain(np.tile([-0.01, 0.01], (2, 1)), WIDE.tension)
    t = SchemaPlan(model, ArmSchema(true_arm, narrow), 2, seed=4).target(0)
    assert t.commanded_by == "geometric" and "far outside" in t.note
    np.testing.assert_array_equal(t.hold_command, g.hold_command)
    low = Domain(WIDE.theta, np.tile([0.0, 20.0], (4, 1)))
    t = SchemaPlan(model, ArmSchema(true_arm, low), 2, seed=4).target(0)
    assert t.commanded_by == "geometric" and "tension far outside" in t.note


def test_a_schema_that_moves_a_path_beyond_its_wires_stretch_is_never_used(model, true_arm):
    """A schema 12 mm short on every wire: more than a wire stretches from slack to f_max
    (6.4 mm at K = 1000), so not this arm: the geometric plan commands the pose."""
    t = SchemaPlan(model, ArmSchema(true_arm, offset=-0.012), 3, seed=4).target(1)
    g = CollectionPlan(model, 3, seed=4).target(1)
    assert t.commanded_by == "geometric"
    assert "the schema moves m0's path -12.4 mm from the description's" in t.note
    np.testing.assert_array_equal(t.approach_length, g.approach_length)
    np.testing.assert_array_equal(t.hold_command, g.hold_command)


def test_the_geometric_verdict_takes_the_schemas_correction_out(model, true_arm):
    """Every real path 5 mm shorter than described: seen by the description, the schema's
    held lengths are 5 mm short and would pull the arm more than 0.2 rad off the pose;
    judged in the description's frame, they are the pose's own, and the schema commands."""
    schema = ArmSchema(true_arm, offset=-0.005)
    t = SchemaPlan(model, schema, 3, seed=4).target(1)
    assert t.commanded_by == "schema" and not t.note
    eq = model.equilibrium(list(t.hold_mode), t.hold_command, theta0=t.theta)
    assert np.abs(eq.theta - t.theta).max() > MAX_POSE_EXCURSION  # what the raw verdict says
    np.testing.assert_allclose(t.hold_command[t.held],
                               schema.length(t.theta, t.tension)[t.held], atol=1e-12)


def test_schema_of_another_arm_is_refused(model):
    other = GeometricSchema(ArmModel.load("left-arm-5dof"))
    other.domain = WIDE
    with pytest.raises(ValueError, match="trained on this robot"):
        SchemaPlan(model, other, 2, seed=0)


def _collect(path, plan, seed: int):
    """Collect with ``plan``; a stop of the simulated boards on a loaded machine (their
    physics shares this process's CPU) is resumed, as a user would."""
    meta = collection_meta(plan.model, plan.meta(), port="virtual", simulated=True,
                           settle={}, move={})
    for attempt in range(4):
        writer, start = open_recording(path, meta, attempt > 0)
        try:
            with open_link("virtual", plan.model.robot, conceal=[ROUTING], seed=seed,
                           speed=20) as link:
                Collector(link, plan.model, plan, writer, start, SettleConfig(window=0.06),
                          move=MoveConfig(speed=20)).run()
            break
        except SafetyStop:
            if attempt == 3:
                raise
    rec = read_recording(path)
    return rec, np.sqrt(np.mean((rec.theta - rec.theta_command) ** 2, axis=0))


def test_a_right_schema_reaches_the_poses_the_model_misses(model, true_arm, tmp_path):
    """Routing 4 mm off: the geometric commands miss by degrees, the true schema's do not."""
    n, seed = 6, 4
    _, geometric = _collect(tmp_path / "g.parquet", CollectionPlan(model, n, seed), seed)
    rec, learned = _collect(tmp_path / "s.parquet",
                            SchemaPlan(model, ArmSchema(true_arm), n, seed), seed)
    assert np.degrees(geometric).max() > 1.0
    assert (learned < geometric / 3).all(), (np.degrees(learned), np.degrees(geometric))
    assert rec.array("commanded_by").tolist() == ["schema"] * n


def _cli_collect(out, *args: str):
    """`pimbs collect` to completion; stops of the simulated boards on a loaded machine are
    resumed (what the error message tells a user to do)."""
    fast = ["--mock-speed", "20", "--settle-window", "0.06", "--port", "virtual"]
    for attempt in range(4):
        res = CliRunner().invoke(main, ["collect", *fast, *args, "--out", str(out),
                                        *(["--resume"] if attempt else [])])
        if res.exit_code == 0 or "--resume" not in res.output:
            return res
    return res


def test_cli_collect_with_a_trained_schema(tmp_path):
    model_dir, _ = small_model(tmp_path, epochs=30)
    out = tmp_path / "s.parquet"
    res = _cli_collect(out, "--samples", "3", "--seed", "2", "--schema", str(model_dir))
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.meta["schema"] == str(model_dir) and len(rec.meta["schema_weights_sha256"]) == 64
    assert set(rec.array("commanded_by").tolist()) <= {"schema", "schema+geometric",
                                                       "geometric"}
    info = CliRunner().invoke(main, ["info", str(out)])
    assert "pose accuracy" in info.output and "body schema" in info.output
    # a geometric collection is not continued with a schema (nor the other way round)
    plain = tmp_path / "g.parquet"
    assert _cli_collect(plain, "--samples", "3", "--seed", "2").exit_code == 0
    res = CliRunner().invoke(main, ["collect", "--port", "virtual", "--samples", "3",
                                    "--seed", "2", "--schema", str(model_dir), "--out",
                                    str(plain), "--resume"])
    assert res.exit_code == 1 and "rerun without --schema" in res.output
    res = CliRunner().invoke(main, ["collect", "--port", "virtual", "--samples", "1",
                                    "--robot", "left-arm-5dof", "--schema", str(model_dir),
                                    "--out", str(tmp_path / "5.parquet")])
    assert res.exit_code == 1 and "trained on this robot" in res.output
