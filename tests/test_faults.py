"""Injected faults: each gives its named stop, and the arm ends relaxed (never slack)."""

from __future__ import annotations

import time

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
        sample, detect_by = -1, None
        with pytest.raises(stop) as err:
            # up to the fault's sample, then at it until detected: frame loss and heating
            # need a moment, which a loaded machine stretches (the deadline is far beyond)
            while detect_by is None or time.monotonic() < detect_by:
                sample = min(sample + 1, fault.sample)
                if sample == fault.sample and detect_by is None:
                    detect_by = time.monotonic() + 10.0
                mock.set_sample(sample)
                driver.command("tension", 60.0)
                driver.dwell(0.15)
            pytest.fail("fault not detected")
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
    with open_arm("virtual", ROBOT, faults=[spec], speed=SPEED, limits=LIMITS) as (driver, mock):
        driver.command("tension", 40.0)
        with pytest.raises(Overheat, match="muscle m2"):
            driver.dwell(10.0)
        # not before its time, on the simulated boards' own clock and cycle count (however
        # long a loaded machine took to start them)
        if trigger == "seconds":
            assert mock._clock() - mock._t0 >= 0.3
        else:
            assert mock._cycles >= 60
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
