"""Arm driver against the simulated boards: virtual CAN bus and pty serial, safe exits."""

from __future__ import annotations

import time
import uuid

import numpy as np
import pytest

from pimbs_arm.model import ArmModel
from pimbs_calibration.description import load_robot
from pimbs_hw import ArmDriver, PortError, SafetyLimits, open_arm
from pimbs_hw.mock import MockArm
from pimbs_hw.safety import TensionLimit, WatchdogExpired
from pimbs_hw.transport import CanTransport
from pimbs_sim.effects import parse_effect

ROBOT = "two-link-4-muscle"
SPEED = 10.0  # settling time constant 7.5 ms


def wait_until(predicate, timeout: float = 2.0, period: float = 0.02) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(period)
    return predicate()


def hold_until(driver, reached, timeout: float = 10.0):
    """Keep the arm commanded (``dwell``) until ``reached(state)``, and the last state.

    The simulated arm settles within a fixed span of *its* time, which a loaded machine
    stretches in wall time (the solver lags, the process waits for a CPU): a test waits for
    the state it checks, with a deadline far beyond an idle machine's time, instead of
    assuming one."""
    end = time.monotonic() + timeout
    state = driver.dwell(0.05)
    while not reached(state) and time.monotonic() < end:
        state = driver.dwell(0.05)
    return driver.dwell(0.05)  # a reading taken once there


def near(values, target, tol: float) -> bool:
    return bool(np.all(np.abs(np.asarray(values) - np.asarray(target)) <= tol))


def channel() -> str:
    return f"virtual:test-{uuid.uuid4().hex}"


@pytest.fixture(scope="module")
def robot():
    return load_robot(ROBOT)


@pytest.mark.parametrize("port", ["virtual", "pty"])
def test_tension_mode_reads_back_through_the_protocol(port, robot):
    with open_arm(port, robot, speed=SPEED, seed=1) as (driver, mock):
        state = driver.read_state()
        assert state.muscles == ("m0", "m1", "m2", "m3") and state.theta.shape == (2,)
        driver.command("tension", [30.0, 40.0, 30.0, 40.0])
        target = [30, 40, 30, 40]
        state = hold_until(driver, lambda s: mock.settled() and near(s.tension, target, 1.5)
                           and near(mock.snapshot().tension, target, 0.5))
        truth = mock.snapshot()
        assert state.tension == pytest.approx([30, 40, 30, 40], abs=1.5)
        assert truth.tension == pytest.approx([30, 40, 30, 40], abs=0.5)
        # lengths: encoder counts of the true length, so exact up to one count
        assert np.abs(state.length - truth.length).max() <= 1.5 / 108650
        assert state.theta == pytest.approx(truth.theta, abs=1e-3)
        state = driver.read_state(timeout=1.0)  # waits for news from every board
        assert state.fresh.all() and (state.age < 0.5).all() and (state.seq >= 0).all()
        assert all(not f for f in state.faults)


def test_position_mode_settles_to_the_model_equilibrium(robot):
    model = ArmModel(robot)
    theta = np.array([0.2, -0.15])
    f = model.tension_distribution(theta, np.full(4, 30.0))
    lengths = model.length(theta, f)
    with open_arm("virtual", robot, speed=SPEED) as (driver, mock):
        driver.command("length", lengths)
        state = hold_until(driver, lambda s: near(s.theta, theta, 2e-3)
                           and near(mock.snapshot().theta, theta, 2e-3))
        assert mock.snapshot().theta == pytest.approx(theta, abs=2e-3)
        assert state.theta == pytest.approx(theta, abs=2e-3)
        assert state.tension == pytest.approx(f, abs=0.05 * f.max())
        assert state.length == pytest.approx(lengths, abs=2e-5)


def test_mixed_modes_and_zero(robot):
    with open_arm("virtual", robot, speed=SPEED) as (driver, mock):
        state = driver.dwell(0.1)
        driver.command(["length", "tension", "relax", "tension"],
                       [state.length[0], 50.0, np.nan, 50.0])
        state = hold_until(driver, lambda s: near(s.tension[1], 50, 1.5))
        assert mock.snapshot().modes == ("position", "tension", "relax", "tension")
        assert state.tension[1] == pytest.approx(50, abs=1.5)
        driver.zero()
        state = driver.read_state()
        assert state.length == pytest.approx(np.zeros(4), abs=3e-5)
        assert state.muscle("m1")["tension"] == state.tension[1]
        driver.stop()
        assert wait_until(lambda: mock.snapshot().modes == ("hold",) * 4)


def test_stale_data_is_flagged():
    with open_arm("virtual", ROBOT, speed=SPEED) as (driver, _):
        driver.read_state()
        again = driver.read_state(timeout=0.0)  # status frames come every 20 ms
        assert not again.fresh.any() and (again.age >= 0).all()
        assert driver.read_state(timeout=2.0).fresh.all()  # returns when every board spoke


def test_tension_commands_clamped_to_ceiling_and_floor(robot):
    limits = SafetyLimits(tension_ceiling=80.0)
    with open_arm("virtual", robot, speed=SPEED, limits=limits) as (driver, mock):
        driver.command("tension", [1e4, 0.0, -5.0, 60.0])
        state = hold_until(driver, lambda s: near(s.tension, [80, 10, 10, 60], 1.5))
        assert state.tension == pytest.approx([80, 10, 10, 60], abs=1.5)


def test_derating_with_temperature():
    limits = SafetyLimits(derate_start_c=60, fault_c=80)
    f = limits.clamp_tension(np.full(3, 500.0), np.full(3, 10.0), np.full(3, 600.0),
                             np.array([25.0, 70.0, 79.9]))
    assert f == pytest.approx([500.0, 305.0, 10.0 + 590 * 0.1 / 20])


def test_limit_breaking_length_command_trips_and_relaxes(robot):
    limits = SafetyLimits(tension_ceiling=100.0)
    with open_arm("virtual", robot, speed=SPEED, limits=limits) as (driver, mock):
        state = driver.dwell(0.1)
        driver.command("length", state.length - 0.006)  # exp(1000 * 0.006) ~ 400 N
        with pytest.raises(TensionLimit) as err:
            driver.dwell(0.5)
        assert err.value.muscle in driver.muscles
        assert f"board {err.value.board_id}" in str(err.value)
        assert wait_until(lambda: mock.snapshot().relaxed().all())
        with pytest.raises(TensionLimit):  # tripped: later commands refused
            driver.command("tension", 20.0)


@pytest.mark.parametrize("ending", ["normal", "exception", "ctrl-c"])
def test_every_exit_relaxes_the_arm(ending, robot):
    link = channel()
    with MockArm(robot, link, speed=SPEED) as mock:
        with pytest.raises((RuntimeError, KeyboardInterrupt)) if ending != "normal" else _null():
            with ArmDriver(CanTransport(link), robot) as driver:
                driver.command("tension", 150.0)
                hold_until(driver, lambda _: near(mock.snapshot().tension, 150.0, 2))
                assert mock.snapshot().tension == pytest.approx(np.full(4, 150.0), abs=2)
                if ending == "exception":
                    raise RuntimeError("collection bug")
                if ending == "ctrl-c":
                    raise KeyboardInterrupt
        assert wait_until(lambda: mock.snapshot().relaxed().all())
        assert mock.snapshot().tension == pytest.approx(np.full(4, 10.0), abs=1)  # not slack


class _null:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_board_watchdog_relaxes_when_the_host_stops_sending(robot):
    with open_arm("virtual", robot, speed=SPEED,
                  limits=SafetyLimits(watchdog_s=0.3, silent_after_s=2.0)) as (driver, mock):
        driver.command("tension", 120.0)
        driver.dwell(0.1)
        assert not mock.snapshot().relaxed().any()
        time.sleep(0.5)  # host "hangs": no commands, no background feeding
        assert wait_until(lambda: mock.snapshot().relaxed().all())
        with pytest.raises(WatchdogExpired, match=r"muscle m\d \(board \d\)"):
            driver.read_state()


def test_concealed_effect_hook_changes_readings(robot):
    effect = parse_effect("tension_offset:15,muscles=m1")
    with open_arm("virtual", robot, speed=SPEED, effect=effect) as (driver, mock):
        driver.command("tension", 40.0)
        state = hold_until(driver, lambda s: near(s.tension, 40.0, 1.5)
                           and near(mock.snapshot().tension, [40, 25, 40, 40], 0.5))
        assert state.tension == pytest.approx(np.full(4, 40.0), abs=1.5)  # boards servo reading
        assert mock.snapshot().tension == pytest.approx([40, 25, 40, 40], abs=0.5)


def test_wrong_ports_are_clear_errors(robot):
    with pytest.raises(PortError, match="pimbsnocan3.*--port virtual"):
        with open_arm("pimbsnocan3", robot):
            pass
    with pytest.raises(ValueError, match="only on the simulated arm"):
        with open_arm("can0", robot, faults=["overheat:m1"]):
            pass


def test_no_boards_on_the_bus_is_a_clear_error(robot):
    from pimbs_hw.safety import BoardSilent

    with pytest.raises(BoardSilent, match="m0 .*m3.*--port virtual"):
        ArmDriver(CanTransport(channel()), robot, connect_timeout_s=0.2)


def test_mockbus_command_serves_a_pty():
    from click.testing import CliRunner

    from pimbs_cli.mockbus import command

    result = CliRunner().invoke(command, ["--serial", "--duration", "0.3", "--fault",
                                          "overheat:m1@0.1s"])
    assert result.exit_code == 0, result.output
    assert "connect with: pimbs collect --port /dev/" in result.output
    bad = CliRunner().invoke(command, ["--serial", "--duration", "0.1", "--fault", "melt:m1"])
    assert bad.exit_code != 0 and "unknown fault kind 'melt'" in bad.output


def test_reconnect_after_a_crashed_host(robot):
    link = channel()
    limits = SafetyLimits(watchdog_s=0.1)
    with MockArm(robot, link, speed=SPEED) as mock:
        crashed = ArmDriver(CanTransport(link), robot, limits)
        crashed.command("tension", 80.0)
        crashed.transport.close()  # the host dies: no relax sent
        assert wait_until(lambda: mock.snapshot().relaxed().all())  # board watchdogs
        # the next session is clean (default watchdog: a loaded machine must not trip it)
        with ArmDriver(CanTransport(link), robot) as driver:
            assert not any(driver.read_state().faults)
            driver.command("tension", 30.0)
            state = hold_until(driver, lambda s: near(s.tension, 30.0, 1.5))
            assert state.tension == pytest.approx(np.full(4, 30.0), abs=1.5)


class _StandInModel:
    """Trivial plant: the equilibrium is the command itself (lengths and tensions as given)."""

    n_muscles, n_joints = 2, 1
    joint_limits = np.array([[-1.0, 1.0]])  # the power-up pose θ = 0 lies within them
    f_max = np.array([600.0, 600.0])  # each motor heats in proportion to its share of it

    def equilibrium(self, mode, command, theta0=None):
        from types import SimpleNamespace

        command = np.asarray(command, float)
        is_length = np.array(mode) == "length"
        return SimpleNamespace(theta=np.array([command.sum()]),
                               tension=np.where(is_length, 0.0, command),
                               length=np.where(is_length, command, 0.0),
                               converged=True, residual=0.0)


def test_plant_settles_first_order_with_speed_factor():
    from pimbs_hw.mock.plant import Plant

    plant = Plant(_StandInModel(), speed=4.0, tau_s=0.08)
    try:
        plant.command(("length", "tension"), np.array([0.01, 50.0]))
        assert wait_until(lambda: plant._solver.idle() and plant._solver.target.length[0] > 0)
        state = plant.step(0.02)  # one time constant: tau / speed
        assert state.length[0] == pytest.approx(0.01 * (1 - np.exp(-1)))
        assert state.tension[1] == pytest.approx(50.0 * (1 - np.exp(-1)))
        assert state.approach[0] == 1  # lengthened into the pose
        for _ in range(20):
            state = plant.step(0.02)
        assert plant.settled() and state.temperature[1] > state.temperature[0]  # load heats
    finally:
        plant.close()
