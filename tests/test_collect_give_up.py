"""A pose the arm overloads or runs off is given up, unloaded, and the collection goes on.

A description that gets a load or a moment arm wrong holds most poses fine and a few not: a
wire pulled far beyond its plan, or a joint whose tension-controlled muscles do not balance
and swings off. The boards' ceiling would stop the whole collection there; the routine
watches below it, unloads that one pose (the slack removal undone from where the arm is),
records it as skipped with a warning that names what happened, and collects the rest.
"""

from __future__ import annotations

import dataclasses
import re
import warnings

import numpy as np
import pytest

from pimbs_arm.model import ArmModel
from pimbs_hw.collection.link import LoadGuard, Overload, Reading
from pimbs_hw.collection.move import MoveConfig, release
from pimbs_hw.collection.plan import CollectionPlan
from pimbs_hw.collection.resume import collection_meta, open_recording
from pimbs_hw.collection.routine import LOAD_LIMIT, Collector
from pimbs_hw.collection.session import open_link
from pimbs_hw.collection.settle import SettleConfig
from pimbs_recording.format import read_recording

SPEED = 5.0  # the simulated arm's time speed-up: its physics shares this process's CPU


class Disturbed:
    """The simulated arm's link, with something the description does not know at one sample:
    from the slack removal of that sample's pose on (mixed length/tension commands after
    its move) until the arm is moved again (the pose given up: a wire moved comes off its
    snag), ``extra`` N more on one wire's
    loadcell (a snag) or the joints ``swing`` rad off (a pose that runs away). Records every
    command, with the sample it belongs to."""

    def __init__(self, link, sample: int, muscle: int = 0, extra: float = 0.0,
                 swing: float = 0.0) -> None:
        self.link, self.sample, self.muscle, self.extra, self.swing = (
            link, sample, muscle, extra, swing)
        self.i, self.mixed, self.sent, self.moves = -1, False, [], 0

    def begin_sample(self, index: int) -> None:
        self.i = index
        self.link.begin_sample(index)

    def command(self, mode, values) -> None:
        # moves of the sample's own (all wires in length), each from a slack removal or start
        self.moves += self.i == self.sample and mode == "length" and (
            not self.sent or self.sent[-1][1] != "length")
        self.mixed = not isinstance(mode, str)
        self.sent.append((self.i, mode, np.array(values, float)))
        self.link.command(mode, values)

    def read(self) -> Reading:
        r = self.link.read()
        if self.i != self.sample or not self.mixed or self.moves != 1:
            return r
        tension = r.tension.copy()
        tension[self.muscle] += self.extra
        return dataclasses.replace(r, tension=tension, theta=r.theta + self.swing)

    def relax(self) -> None:
        self.link.relax()


@pytest.fixture(scope="module")
def model() -> ArmModel:
    return ArmModel.load("two-link-4-muscle")


class QuasiStatic(Disturbed):
    """The same, telling the routine what the built-in arm tells it: it cannot swing."""

    quasi_static = True

    def at_rest(self) -> bool | None:
        return self.link.at_rest()


def _collect(path, model, disturb: dict, kind: type[Disturbed] = Disturbed, sample: int = 2
             ) -> tuple[Collector, Disturbed]:
    plan = CollectionPlan(model, 4, seed=4)
    meta = collection_meta(model, plan.meta(), port="virtual", simulated=True, settle={},
                           move={})
    writer, start = open_recording(path, meta, False)
    with open_link("virtual", model.robot, seed=4, speed=SPEED) as link:
        arm = kind(link, sample=sample, **disturb)
        collector = Collector(arm, model, plan, writer, start, SettleConfig(window=0.06),
                              move=MoveConfig(speed=SPEED))
        collector.run()
    return collector, arm


def test_a_snagged_wire_gives_up_its_pose_and_the_collection_goes_on(model, tmp_path):
    f_max = model.robot.muscles[1].f_max
    collector, arm = _collect(tmp_path / "snag.parquet", model,
                              {"muscle": 1, "extra": f_max})
    s = collector.summary
    assert s.complete and s.skipped == [2]
    assert read_recording(tmp_path / "snag.parquet").sample.tolist() == [0, 1, 3]
    (warning,) = [w for w in s.warnings if "given up" in w]
    assert warning.startswith("sample 2 given up: m1 pulled ")
    assert f"(load limit {LOAD_LIMIT * f_max:.0f} N)" in warning
    assert "the plan holds it at" in warning
    # the pose was unloaded to its low-tension approach (the lengths of where the arm stood,
    # at the pose within microns), then the arm went back to the last pose recorded
    plan = CollectionPlan(model, 4, seed=4)
    target = plan.target(2)
    sent = [(mode, values) for i, mode, values in arm.sent if i == 2]
    _, last = [c for c in sent if c[0] == target.hold_mode][-1]
    np.testing.assert_allclose(last[target.held], target.approach_length[target.held],
                               atol=2e-5)
    approach = plan.holding(target.theta, target.tension).approach_tension
    np.testing.assert_allclose(last[~target.held], approach[~target.held], rtol=1e-6)
    # ... loaded as it was held there, where the next move starts: the arm is never relaxed
    before = plan.target(1)
    assert sent[-1][0] == before.hold_mode
    np.testing.assert_allclose(sent[-1][1], before.hold_command)
    assert not any(mode == "relax" for mode, _ in sent)


def test_a_first_pose_given_up_starts_over_from_the_relaxed_arm(model, tmp_path):
    """Before any pose is recorded there is none to go back to: the arm is relaxed."""
    f_max = model.robot.muscles[1].f_max
    collector, arm = _collect(tmp_path / "first.parquet", model,
                              {"muscle": 1, "extra": f_max}, sample=0)
    assert collector.summary.skipped == [0]
    assert read_recording(tmp_path / "first.parquet").sample.tolist() == [1, 2, 3]
    assert [mode for i, mode, _ in arm.sent if i == 0][-1] == "relax"


def test_a_pose_that_runs_away_is_given_up(model, tmp_path):
    collector, _ = _collect(tmp_path / "swing.parquet", model, {"swing": 0.3})
    s = collector.summary
    assert s.complete and s.skipped == [2]
    (warning,) = [w for w in s.warnings if "given up" in w]
    assert re.match(r"sample 2 given up: the joints ran 0\.3\d rad off the pose", warning)
    assert "do not balance this pose" in warning


def test_a_quasi_static_arm_that_settles_off_the_pose_gives_it_up(model, tmp_path):
    """The quasi-static arm is not waited for before its wires are loaded (its joints still
    creep toward the pose then), so its pose is judged where it settles: off by more than
    the limit, it is given up all the same, and the rest are recorded."""
    collector, _ = _collect(tmp_path / "creep.parquet", model, {"swing": 0.3}, QuasiStatic)
    s = collector.summary
    assert collector.move.quasi_static
    assert s.complete and s.skipped == [2]
    (warning,) = [w for w in s.warnings if "given up" in w]
    assert re.match(r"sample 2 given up: the joints ran 0\.3\d rad off the pose", warning)
    assert read_recording(tmp_path / "creep.parquet").sample.tolist() == [0, 1, 3]


def test_the_guard_watches_only_while_loading():
    reading = Reading(np.zeros(2), np.array([10.0, 700.0]), np.zeros(2), np.zeros(1))

    class Fixed:
        def read(self) -> Reading:
            return reading

    guard = LoadGuard(Fixed(), np.array([570.0, 570.0]), 0.2, ("a", "b"))
    assert guard.read() is reading  # unloading a pose never raises
    with guard.watching(), pytest.raises(Overload, match="b pulled 700 N"):
        guard.read()
    assert not guard.armed
    reading = Reading(np.zeros(2), np.array([10.0, 20.0]), np.zeros(2), np.array([0.5]))
    with guard.watching():
        assert guard.read() is reading  # moving toward the pose: no pose to stay near yet
        guard.pose = np.zeros(1)
        with pytest.raises(Overload, match="ran 0.50 rad off the pose"):
            guard.read()


def test_a_narrow_joint_is_given_up_before_it_runs_onto_its_stop():
    """0.2 rad off the pose is a fifth of a 1 rad range, but most of a 0.17 rad one: each
    joint may run a fifth of its range off (0.1 rad at least, 0.2 at most)."""
    from types import SimpleNamespace

    from pimbs_hw.collection.plan import pose_excursion

    arm = SimpleNamespace(joint_range=np.array([[-1.0, 1.0], [-0.35, 0.35], [-0.087, 0.087]]))
    np.testing.assert_allclose(pose_excursion(arm), [0.2, 0.14, 0.1])
    theta = np.array([0.15, 0.0, 0.0])

    class Fixed:
        def read(self) -> Reading:
            return Reading(np.zeros(2), np.array([10.0, 20.0]), np.zeros(2), theta)

    guard = LoadGuard(Fixed(), np.array([570.0, 570.0]), pose_excursion(arm), ("a", "b"))
    with guard.watching():
        guard.pose = np.zeros(3)
        guard.read()  # the wide joint 0.15 rad off: within its 0.2
        theta = np.array([0.0, 0.15, 0.0])
        with pytest.raises(Overload, match=r"ran 0.15 rad off the pose \(limit 0.14 rad\)"):
            guard.read()


def test_releasing_a_pose_given_up_far_from_it_is_a_short_ramp(model):
    """A pose given up mid-swing is released from lengths the model reads as a stretch whose
    exponential tension no wire carries (a MuJoCo torso on itself: 1e15 steps, and numpy
    could not allocate them). The ramp's tension spacing stops at f_max: it stays short,
    finite, and still ends at the approach."""
    target = CollectionPlan(model, 2, seed=0).target(0)
    assert target.held.any()
    now = Reading(length=target.approach_length - 0.05,
                  tension=np.full(model.n_muscles, 900.0),
                  temperature=np.full(model.n_muscles, 25.0), theta=target.theta + 0.3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow reaches the user's screen
        ramp = release(model, now, target, MoveConfig())
    assert 2 <= len(ramp.commands) <= 1000
    assert all(np.isfinite(c).all() for c in ramp.commands)
    np.testing.assert_allclose(ramp.commands[-1][target.held],
                               target.approach_length[target.held])
