"""Injected faults: each gives its named stop, and the arm ends relaxed (never slack)."""

from __future__ import annotations

import numpy as np
import pytest

from pimbs_hw import SafetyLimits, open_arm
from pimbs_hw.mock import FaultSpec, FaultSpecError, parse_fault
from pimbs_hw.safety import (
    BoardSilent,
    BusOff,
    CorruptFrames,
    FramesDropped,
    LoadcellSaturated,
    Overheat,
    SafetyStop,
)
from tests.test_driver_mock import SPEED, wait_until

ROBOT = "two-link-4-muscle"
LIMITS = SafetyLimits(watchdog_s=0.6)  # as for any simulated arm: a loaded host is slow


@pytest.mark.parametrize("port, spec, stop", [
    ("virtual", "silent-board:m1@2", BoardSilent),
    ("virtual", "drop-frames:m2@2", FramesDropped),
    ("virtual", "corrupt-frames:m3@2", CorruptFrames),
    ("virtual", "overheat:m0@2", Overheat),
    ("virtual", "saturate-loadcell:m1@2", LoadcellSaturated),
    ("virtual", "bus-off@2", BusOff),
    ("pty", "corrupt-frames:m2@1", CorruptFrames),
    ("pty", "bus-off@1", BusOff),
])
def test_fault_gives_named_stop_and_relaxed_arm(port, spec, stop):
    fault = parse_fault(spec)
    with open_arm(port, ROBOT, faults=[spec], speed=SPEED, limits=LIMITS) as (driver, mock):
        with pytest.raises(stop) as err:
            for sample in range(10):
                mock.set_sample(sample)
                driver.command("tension", 60.0)
                driver.dwell(0.15)
                # detected at its sample, or (frame loss and heating need a moment) just after
                assert sample < fault.sample + 3, "fault not detected"
        assert sample >= fault.sample, "fault fired too early"
        if fault.muscle is None:
            assert err.value.port == mock.port and mock.port in str(err.value)
        else:
            i = driver.muscles.index(fault.muscle)
            assert err.value.muscle == fault.muscle and err.value.board_id == driver.board_ids[i]
            assert f"muscle {fault.muscle} (board {driver.board_ids[i]})" in str(err.value)
        # every board relaxes: by the driver's relax, or (bus-off) by its own watchdog
        assert wait_until(lambda: mock.snapshot().relaxed().all(), timeout=2.0)
        assert mock.snapshot().tension == pytest.approx(np.full(4, 10.0), abs=1.0)
        with pytest.raises(SafetyStop):
            driver.command("tension", 60.0)


@pytest.mark.parametrize("spec, trigger", [("overheat:m2@0.3s", "seconds"),
                                           ("overheat:m2@60c", "cycles")])
def test_time_and_cycle_triggers(spec, trigger):
    with open_arm("virtual", ROBOT, faults=[spec], speed=SPEED, limits=LIMITS) as (driver, _):
        driver.command("tension", 40.0)
        driver.dwell(0.15)  # not yet
        with pytest.raises(Overheat, match="muscle m2"):
            driver.dwell(2.0)
    assert getattr(parse_fault(spec), trigger) is not None


def test_fault_spec_parsing():
    assert parse_fault("overheat:m2@10") == FaultSpec("overheat", "m2", sample=10)
    assert parse_fault("bus-off") == FaultSpec("bus-off", None)
    assert parse_fault("drop-frames:*@1.5s") == FaultSpec("drop-frames", None, seconds=1.5)
    assert parse_fault("silent-board:m0@200c") == FaultSpec("silent-board", "m0", cycles=200)
    with pytest.raises(FaultSpecError, match="unknown fault kind 'melt'"):
        parse_fault("melt:m1@3")
    with pytest.raises(FaultSpecError, match="unknown muscle 'm9'.*m0, m1"):
        parse_fault("overheat:m9@3", ("m0", "m1"))
    with pytest.raises(FaultSpecError, match="form is"):
        parse_fault("overheat:m1@soon")
