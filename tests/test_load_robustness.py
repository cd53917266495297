"""What a loaded machine does to hardware-in-the-loop runs, checked without wall-clock timing.

A descheduled host or a slow equilibrium solver must change only how long things take, never
what the (simulated) arm does: the arm moves only toward the equilibrium of the commands in
force, and a ramp that fell behind is re-timed instead of sent in a burst.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

import pimbs_hw.collection.move as move_module
from pimbs_arm.model import ArmModel
from pimbs_calibration.description import load_robot
from pimbs_hw.collection.link import Reading
from pimbs_hw.collection.move import Ramp, run_ramp
from pimbs_hw.mock.plant import Plant


@pytest.fixture(scope="module")
def model() -> ArmModel:
    return ArmModel(load_robot("two-link-4-muscle"))


def test_plant_holds_still_while_the_solver_is_behind(model):
    """Under load the solver lags: the arm must not relax toward the previous commands'
    equilibrium meanwhile (with friction that delay loop oscillated into the ceiling)."""
    plant = Plant(model, speed=5.0)
    gate = threading.Event()
    solve = model.equilibrium

    def slow(*args, **kwargs):
        gate.wait(10.0)
        return solve(*args, **kwargs)

    plant._solver._model = type("Slow", (), {"equilibrium": staticmethod(slow)})()

    def wait_idle() -> None:
        for _ in range(1000):
            if plant._solver.idle():
                return
            threading.Event().wait(0.01)
        raise AssertionError("solver never finished")

    try:
        m = model.n_muscles
        gate.set()
        plant.command(("tension",) * m, np.full(m, 60.0))  # A: solved at once ...
        wait_idle()
        before = plant.state  # ... but the arm has not moved toward it yet
        gate.clear()
        plant.command(("tension",) * m, np.full(m, 120.0))  # B: the solver is slow now
        for _ in range(20):  # a second of wall time at 5x: far past the time constant
            state = plant.step(0.05)
        np.testing.assert_array_equal(state.theta, before.theta)
        np.testing.assert_array_equal(state.tension, before.tension)
        gate.set()
        wait_idle()
        for _ in range(20):
            state = plant.step(0.05)
        target = plant._solver.target
        np.testing.assert_allclose(state.tension, target.tension, atol=1e-3)
        assert np.abs(state.tension - before.tension).max() > 1.0
    finally:
        gate.set()
        plant.close()


class _Clock:
    """A fake clock: sleeping advances it; the link can stall it."""

    def __init__(self) -> None:
        self.t = 0.0

    def monotonic(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += s


def test_a_stalled_ramp_is_retimed_not_sent_in_a_burst(monkeypatch):
    clock = _Clock()
    monkeypatch.setattr(move_module, "time", clock)
    sent: list[float] = []

    class Link:
        def command(self, mode, values) -> None:
            sent.append(clock.t)

        def read(self) -> Reading:
            if len(sent) == 3:
                clock.t += 0.5  # the host was descheduled for half a second
            z = np.zeros(2)
            return Reading(z, z, z)

    commands = [np.full(2, k * 1e-3) for k in range(11)]
    run_ramp(Link(), Ramp("length", commands, duration=1.0))  # one command per 0.1 s
    gaps = np.diff(sent)
    assert len(sent) == 11
    assert gaps.min() >= 0.1 - 1e-9, gaps  # never two commands closer than the schedule
    assert gaps.max() == pytest.approx(0.5)  # the stall itself, and nothing squeezed after it
