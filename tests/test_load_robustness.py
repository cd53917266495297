"""What a loaded machine does to hardware-in-the-loop runs, checked without wall-clock timing.

A descheduled host or a slow equilibrium solver must change only how long things take, never
what the (simulated) arm does: the arm moves only toward the equilibrium of the commands in
force, and a ramp that fell behind is re-timed instead of sent in a burst.
"""

from __future__ import annotations

import threading
import time

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


def test_a_tick_that_ran_late_is_followed_by_every_frame_that_came_meanwhile():
    """The simulated boards act on every frame that reached them before the next tick starts,
    however late the last tick ran: acting on one frame per late tick (a loaded machine)
    left a growing backlog, and the arm followed commands seconds old into the ceiling."""
    from types import SimpleNamespace

    from pimbs_hw.mock.arm import MockArm

    queue: list[SimpleNamespace] = []
    handled: list[SimpleNamespace] = []
    seen_at_tick: list[tuple[int, int]] = []  # (frames handled, frames sent) at each tick
    sent = [0]
    stop = threading.Event()

    class Transport:
        def recv(self, timeout: float):
            if queue:
                return queue.pop(0)
            stop.wait(min(timeout, 0.005))
            return None

    def tick(now: float) -> None:
        seen_at_tick.append((len(handled), sent[0]))
        if len(seen_at_tick) == 6:
            stop.set()
            return
        for _ in range(4):  # one host cycle's frames reach the boards during this tick
            sent[0] += 1
            queue.append(SimpleNamespace(timestamp=time.monotonic()))
        time.sleep(0.03)  # the tick runs three periods late

    arm = MockArm.__new__(MockArm)
    arm.transport, arm.tick_s, arm._stop, arm._commanded = Transport(), 0.01, stop, False
    arm._on_frame, arm._tick, arm._clock = handled.append, tick, time.monotonic
    runner = threading.Thread(target=arm._run, daemon=True)
    runner.start()
    runner.join(30.0)
    assert not runner.is_alive() and len(seen_at_tick) == 6
    for handled_then, sent_then in seen_at_tick:
        assert handled_then == sent_then, seen_at_tick


def test_a_relax_not_yet_followed_is_not_taken_for_rest():
    """Before a move the arm must be at rest; a relax the boards have not begun to follow yet
    (boards or a simulated arm behind, as on a loaded machine) reads as still as one at rest,
    and the move planned from there started where the arm was about to leave."""
    from pimbs_hw.collection.routine import Collector
    from pimbs_hw.collection.settle import SettleConfig

    floor = np.full(2, 10.0)
    reads = [0]

    class Link:
        def command(self, mode, values) -> None:
            pass

        def read(self) -> Reading:
            reads[0] += 1
            tension = floor if reads[0] > 40 else np.zeros(2)  # the boards follow late
            z = np.zeros(2)
            return Reading(z, tension, z)

        def at_rest(self) -> None:
            return None  # judged from the readings, as on a real arm

    collector = Collector.__new__(Collector)
    collector.link, collector.settle = Link(), SettleConfig(window=0.02, timeout=60.0)
    collector.model = type("Model", (), {"muscles": ("a", "b")})()
    rested = collector._rest("relax", floor)
    assert rested.settled and reads[0] > 40
    np.testing.assert_allclose(rested.reading.tension, floor)
