"""Ramps that wait for an arm slower than its motors, and unloading where the arm really is.

The arm in these tests lags its motors by reads, not by wall time: each read it closes a
tenth of the gap to its motor, and the wire between them pulls 1 N per mm of that gap. The
outcome then does not depend on how busy the machine is.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pimbs_arm.model import ArmModel
from pimbs_hw.collection.link import Reading
from pimbs_hw.collection.move import MoveConfig, Ramp, move, release, run_ramp
from pimbs_hw.collection.plan import CollectionPlan
from pimbs_hw.collection.relax import relax_fall

MOTOR_FINGER = Path(__file__).parent.parent / "fixtures/myosuite/finger/motorfinger_v0.xml"
N_PER_M = 1000.0  # the lagging arm's wire: 1 N per mm between motor and arm


class LaggingArm:
    """One wire: the arm closes 10 % of its gap to the motor per read; ``load`` N more pull
    on the wire whatever the arm does (a weight the description does not know)."""

    def __init__(self, load: float = 0.0) -> None:
        self.motor = self.arm = 0.0
        self.load = load
        self.sent: list[float] = []
        self.tensions: list[float] = []

    def command(self, mode, values) -> None:
        self.motor = float(values[0])
        self.sent.append(self.motor)

    def read(self) -> Reading:
        self.arm += 0.1 * (self.motor - self.arm)
        tension = N_PER_M * max(self.motor - self.arm, 0.0) + self.load
        self.tensions.append(tension)
        return Reading(np.array([self.motor]), np.array([tension]), np.array([25.0]))


def _fast_ramp(paced: bool, stall_s: float = 0.5) -> Ramp:
    """1 mm per command over 20 mm, all sent at once: far faster than the arm follows."""
    commands = [np.array([x]) for x in np.linspace(0.0, 0.02, 21)]
    if not paced:
        return Ramp("length", commands, duration=0.0)
    return Ramp("length", commands, duration=0.0, expected=np.zeros((21, 1)),
                allowance=np.full((21, 1), 2.0), stall_s=stall_s)


def test_a_ramp_waits_for_an_arm_that_lags_its_motors():
    unpaced, paced = LaggingArm(), LaggingArm()
    run_ramp(unpaced, _fast_ramp(paced=False))
    run_ramp(paced, _fast_ramp(paced=True))
    # unpaced, the wire takes the whole lag: the motor ends ~8 mm ahead of the arm
    assert max(unpaced.tensions) > 7.5
    # paced, no reading exceeds the allowance by more than one command's step (1 N)
    assert max(paced.tensions) <= 2.0 + 1.0 + 1e-9
    assert paced.sent[-1] == 0.02  # and the ramp still ends where it was going
    assert len(paced.sent) > 21    # it held commands while the arm caught up


def test_a_load_the_description_does_not_know_is_waited_for_once():
    arm = LaggingArm(load=5.0)  # reads 5 N over the expectation however long it waits
    run_ramp(arm, _fast_ramp(paced=True, stall_s=0.05))
    repeats = [i for i in range(1, len(arm.sent)) if arm.sent[i] == arm.sent[i - 1]]
    assert repeats, "the first command over the allowance is held"
    # after that one stall the excess counts as known: no command is held again for it
    # (the arm's own lag on top stays within the allowance at 1 mm a command)
    first_after = next(i for i in range(repeats[0], len(arm.sent))
                       if arm.sent[i] != arm.sent[repeats[0]])
    assert arm.sent[-1] == 0.02
    assert max(arm.tensions[first_after:]) < 5.0 + 2.0 + 1.0 + 1e-9


def test_a_pose_given_up_on_the_way_is_unloaded_where_the_arm_stands():
    model = ArmModel.load("two-link-4-muscle")
    plan = CollectionPlan(model, 2, seed=0)
    target = plan.target(0)
    short = target.theta * 0.3  # the arm stopped a long way short of the pose
    f_now = np.where(target.held, 0.5 * model.f_max, target.tension)
    now = Reading(model.length(short, f_now), f_now, np.full(model.n_muscles, 25.0), short)
    ramp = release(model, now, target, MoveConfig(), theta=short)
    pretension = model.tension_from_stretch(model.h_geom(target.theta)
                                            - target.approach_length)
    held = target.held
    np.testing.assert_allclose(ramp.commands[-1][held],
                               model.length(short, pretension)[held])
    # every held wire pays out from where it is: none is wound on toward the far pose
    for command in ramp.commands:
        assert np.all(command[held] >= now.length[held] - 1e-12)


def test_a_move_names_the_first_pose_on_its_way_that_no_tensions_hold():
    model = ArmModel.load(MOTOR_FINGER)
    plan = CollectionPlan(model, 1, seed=0)
    target = plan.target(0)
    start = np.array([0.0, 1.047, 0.434, 0.046])  # the finger hanging on its knuckle's stop
    floor = np.array([m.f_floor for m in model.robot.muscles])
    now = Reading(model.length(start, floor), floor, np.full(model.n_muscles, 25.0), start)
    way = move(model, now, start, target, MoveConfig(), plan.balance)
    assert way.unheld is not None
    # that pose is on the straight way, and the plan's own QP indeed cannot hold it
    s = (way.unheld - start) / (target.theta - start)
    np.testing.assert_allclose(s, s[0])
    assert 0.0 <= s[0] < 1.0


def test_relaxing_onto_a_stop_the_muscles_cannot_lift_the_arm_from_is_refused():
    fall = relax_fall(ArmModel.load(MOTOR_FINGER))
    assert fall is not None
    assert "IFmcp=1.047" in fall  # the knuckle's stop
    assert "more than its f_max" in fall and "only its stops carry it there" in fall
    assert relax_fall(ArmModel.load("two-link-4-muscle")) is None


def test_a_run_given_up_on_ways_no_tensions_hold_says_so():
    from pimbs_hw.collection.routine import Summary

    s = Summary(path="f.parquet", total=5, start=0, next_sample=5, skipped=[0, 1, 2, 3, 4],
                unheld_ways=4)
    assert s.failed == ("no pose was recorded: all 5 tried were given up, 4 of them on ways "
                        "that pass poses the description's muscles cannot hold")
    s.unheld_ways = 2  # most were given up for other reasons: nothing said of the ways
    assert s.failed == "no pose was recorded: all 5 tried were given up"


ELBOW = Path(__file__).parent.parent / "fixtures/myosuite/elbow/myoelbow_1dof6muscles.xml"


def test_the_swing_of_an_arm_on_one_held_wire_is_that_of_a_mass_on_a_spring():
    """One held wire on a one-joint arm: ω² = K(f + 1)·G² / I, I from MuJoCo itself."""
    import mujoco

    from pimbs_hw.collection.move import swing_period

    model = ArmModel.load(ELBOW)
    theta = np.array([0.8])
    mj = mujoco.MjModel.from_xml_path(str(ELBOW))
    data = mujoco.MjData(mj)
    joint = mj.joint(model.joints[0])
    data.qpos[joint.qposadr] = theta
    mujoco.mj_forward(mj, data)
    full = np.zeros((mj.nv, mj.nv))
    mujoco.mj_fullM(mj, data, full)
    inertia = full[joint.dofadr[0], joint.dofadr[0]]
    np.testing.assert_allclose(model.inertia(theta), [[inertia]], rtol=1e-12)
    held = np.zeros(model.n_muscles, bool)
    held[3] = True
    tension = np.full(model.n_muscles, 120.0)
    G = model.muscle_jacobian(theta)[3, 0]
    expected = 2 * np.pi * np.sqrt(inertia / (model.K[3] * 121.0 * G**2))
    np.testing.assert_allclose(swing_period(model, theta, held, tension), expected, rtol=1e-9)
    assert swing_period(model, theta, np.zeros(model.n_muscles, bool), tension) == 0.0


def test_a_load_ramp_lasts_two_swings_of_the_arm_except_on_a_quasi_static_one():
    from pimbs_hw.collection.move import (
        RAMP_CYCLE_S,
        SWING_PERIODS,
        swing_period,
        take_up_slack,
    )

    model = ArmModel.load(ELBOW)
    plan = CollectionPlan(model, 3, seed=0)
    target = plan.target(1)
    pretension = model.tension_from_stretch(model.h_geom(target.theta)
                                            - target.approach_length)
    now = Reading(target.approach_length, pretension, np.full(model.n_muscles, 25.0),
                  target.theta)
    swing = swing_period(model, target.theta, target.held, (pretension + target.tension) / 2)
    assert swing > 0.1  # this elbow swings slowly enough to matter
    ramp = take_up_slack(model, now, target, MoveConfig())
    assert ramp.duration >= SWING_PERIODS * swing - 1e-12
    # stretched to the swing, it still sends a command every cycle (the boards' watchdogs)
    assert ramp.duration / (len(ramp.commands) - 1) <= RAMP_CYCLE_S + 1e-12
    quick = take_up_slack(model, now, target, MoveConfig(quasi_static=True))
    assert quick.duration < SWING_PERIODS * swing


class CreepingJoints:
    """One motor at its command; a joint that creeps toward it, closing 10 % of the gap per
    read (1 s apart on the fake clock)."""

    def __init__(self) -> None:
        self.motor, self.theta = 0.0, 0.0
        self.t = 0.0

    def command(self, mode, values) -> None:
        self.motor = float(values[0])

    def read(self) -> Reading:
        self.theta += 0.1 * (1.0 - self.theta)
        return Reading(np.array([self.motor]), np.array([10.0]), np.array([25.0]),
                       np.array([self.theta]))


def _reached_after(config) -> int:
    from pimbs_hw.collection.settle import hold_until_settled

    arm = CreepingJoints()
    clock = iter(np.arange(0.0, 1e4, 0.01))
    held = hold_until_settled(arm, "length", np.array([0.0]), config,
                              clock=lambda: float(next(clock)), sleep=lambda s: None)
    assert held.settled
    return held.readings


def test_at_the_overshoot_an_arm_that_swings_is_waited_for_and_a_quasi_static_one_is_not():
    """The final approach must not start while an arm with inertia still moves; the built-in
    quasi-static arm cannot swing, so only its motors are waited for (its joints creep on
    toward the pose, and the final settle waits for them)."""
    from pimbs_hw.collection.settle import SettleConfig

    settle = SettleConfig()
    tol = np.array([np.inf])
    swinging = _reached_after(settle.overshot(1e-3, tol))
    quasi_static = _reached_after(settle.overshot(1e-3, tol, swings=False))
    assert quasi_static <= settle.min_readings
    # the joints crept until their drift over the window fell below the joint tolerance
    assert swinging > 40
