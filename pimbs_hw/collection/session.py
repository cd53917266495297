"""Connecting a collection to its arm, and the advice a person needs when the arm stops.

The driver's ``SafetyStop`` says *what* happened and where (muscle, board, port); this module
adds *what to do*, and turns a failure to connect (wrong port, no board answers, a robot
description that does not match the boards) into one clear ``ConnectError``.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from pimbs_calibration.description import RobotDescription
from pimbs_hw import open_arm
from pimbs_hw.collection.link import DriverLink, SimulatedArmFailed
from pimbs_hw.collection.plan import CollectionPlan
from pimbs_hw.errors import HardwareError
from pimbs_hw.safety import (
    BoardSilent,
    BusOff,
    CorruptFrames,
    FramesDropped,
    LinkLost,
    LoadcellSaturated,
    Overheat,
    SafetyStop,
    TensionLimit,
    WatchdogExpired,
)
from pimbs_sim.effects import parse_effect


class ConnectError(HardwareError):
    """The arm on ``--port`` could not be brought up; the message says what to check."""


@contextlib.contextmanager
def open_link(port: str, robot: RobotDescription, *, faults: Sequence[str] = (),
              conceal: Sequence[str] = (), seed: int = 0, speed: float = 1.0,
              zero_m=None, plant: Path | None = None,
              plant_damping: dict[str, float] | None = None,
              hold: bool = False) -> Iterator[DriverLink]:
    """``DriverLink`` to the arm on ``port`` (simulated arm for ``virtual``/``pty``; with
    ``plant``, an MJCF that MuJoCo integrates as that arm, its joints given
    ``plant_damping``, see ``Ringing.calming``). ``hold``: the motors hold their
    lengths when the boards are configured, instead of relaxing (``relax.relax_fall``).

    On the way out (normally, on a stop or on Ctrl-C) the driver relaxes the arm.
    """
    effects = [parse_effect(spec, seed=seed) for spec in conceal]
    with contextlib.ExitStack() as stack:
        try:
            driver, mock = stack.enter_context(open_arm(
                port, robot, faults=list(faults), effect=effects or None, seed=seed,
                speed=speed, zero_m=zero_m, hold_at_start=hold,
                mock_options=None if plant is None else {"plant": plant,
                                                         "plant_damping": plant_damping}))
        except SafetyStop as stop:
            raise ConnectError(
                f"no working arm on port {port!r}: {stop.detail}. If the boards are powered and "
                f"the port is right, check that --robot {robot.name} ({robot.muscle_path}) "
                f"describes the boards on this bus (board ids "
                f"{', '.join(str(m.board_id) for m in robot.muscles)})"
                # what boards that answered said about themselves (silent ones say nothing)
                + ("" if isinstance(stop, BoardSilent) else f". Arm left: {stop.end_state}")
            ) from stop
        yield DriverLink(driver, mock)


_ADVICE_TENSION = "check that wire for a snag or a jump off its pulley, and its f_max"
_ADVICE: tuple[tuple[type[SafetyStop], str], ...] = (
    (BoardSilent, "check that board's power, CAN cable and connectors"),
    (Overheat, "let that motor cool down; a long run at high tension heats it (--map al "
               "holds lower tensions)"),
    (TensionLimit, _ADVICE_TENSION),
    (LoadcellSaturated, "check that loadcell's wiring and its calibration in the robot file"),
    (FramesDropped, "check the bus wiring, termination (120 ohm at both ends) and bitrate"),
    (CorruptFrames, "check the bus wiring, termination (120 ohm at both ends) and bitrate"),
    (BusOff, "check the bus wiring, termination (120 ohm at both ends) and bitrate"),
    (WatchdogExpired, "this computer stalled for longer than the board watchdog; close other "
                      "heavy programs"),
    (LinkLost, "the adapter went away: replug it (and check the port name)"),
)


def simulation_cause(stop: SafetyStop, link: DriverLink | None) -> SafetyStop:
    """The stop to report: the simulated arm's own failure where it had one (a blown-up
    MuJoCo step reaches a board's ceiling or its loadcell's rail first), else ``stop``."""
    failure = None if link is None or link.mock is None else link.mock.failure()
    if failure is None or isinstance(stop, SimulatedArmFailed):
        return stop
    cause = SimulatedArmFailed(failure, port=stop.port)
    cause.end_state = stop.end_state
    return cause


def stop_advice(stop: SafetyStop, plan: CollectionPlan | None = None,
                sample: int | None = None, rings: str = "") -> str:
    """The stop's message plus what to do about it before ``--resume``.

    A tension ceiling names the pose and what the model says about it: if the plan needed
    that tension the plan is wrong (an infeasible pose; resuming would stop there again),
    otherwise the wire met something the model does not know: a snag on a real arm, or, on
    a simulated arm warned as barely damped (``rings``: that warning), its own swing.
    """
    todo = next((text for kind, text in _ADVICE if isinstance(stop, kind)),
                "inspect the arm")
    state = getattr(stop, "end_state", "relaxed")
    state = "The arm was relaxed" if state == "relaxed" else f"Arm left {state}"
    if isinstance(stop, SimulatedArmFailed):  # its message says what happened and what to do
        return f"{stop}. {state}."
    if isinstance(stop, TensionLimit) and plan is not None and sample is not None \
            and sample < plan.n_samples:
        return f"{stop}. {state}. {ceiling_verdict(stop, plan, sample, rings)}"
    return f"{stop}. {state}. What to do: {todo}; then rerun with --resume."


def ceiling_verdict(stop: TensionLimit, plan: CollectionPlan, sample: int,
                    rings: str = "") -> str:
    """Where the ceiling was reached and whether the model's plan asked for that tension
    (``rings``: the simulated arm was warned to be barely damped, see ``stop_advice``)."""
    model = plan.model
    target = plan.target(sample)
    # the most the plan asks of each wire: the holding tension, or a tension overshoot
    asked = np.where(target.held, target.tension,
                     np.maximum(target.tension, target.overshoot_command))
    names = list(model.muscles)
    k = names.index(stop.muscle) if stop.muscle in names else int(np.argmax(asked / model.f_max))
    pose = ", ".join(f"{j}={t:.3f}" for j, t in zip(model.joints, target.theta, strict=True))
    where = (f"At sample {sample} (pose {pose} rad) the model's plan asks at most "
             f"{asked[k]:.0f} N of {names[k]} (f_max {model.f_max[k]:.0f} N): ")
    if asked[k] >= model.f_max[k]:
        return (where + "the plan needed that tension (an infeasible pose); this sample "
                "would stop again on --resume. Check the robot description with `pimbs robot` "
                "(routing, masses, f_max) before resuming")
    if rings:
        return (where + "the plan did not need that tension: the simulated arm is barely "
                "damped (warned before it moved), so it swings after each load step and a held "
                "wire takes the swing. Nothing on an arm failed: give the plant's joints the "
                "damping that warning suggests, then rerun with --resume")
    return (where + "the plan did not need that tension, so something the model does not "
            f"know pulled it (a snag). What to do: {_ADVICE_TENSION}; then rerun with --resume")
