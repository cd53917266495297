"""A board is silent only while the host could have heard it: time in which this process
could not run (another job's load, a call holding the GIL) is the host's stall, not the
board's, and never hides a board that stays silent far beyond the limit."""

from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager

import numpy as np
import pytest

import pimbs_hw.driver as driver_module
from pimbs_hw.connect import open_arm
from pimbs_hw.host_lag import HostLag, host_lag
from pimbs_hw.safety import BoardSilent, SafetyLimits, WatchdogExpired


@contextmanager
def stalled(seconds: float):
    """No other thread of this process runs for ``seconds`` (what a call holding the GIL,
    or a machine whose every core is busy, does to it); yields the stall's (start, end)."""
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1000.0)  # this thread keeps the GIL while it spins
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            pass
        span = (t0, time.monotonic())
    finally:
        sys.setswitchinterval(interval)
    time.sleep(0.02)  # the other threads get the GIL back, as after any stall
    yield span


def test_a_stall_of_the_process_is_measured():
    lag = host_lag()
    lag.total(time.monotonic())  # starts the probe
    time.sleep(0.05)
    with stalled(0.6) as (t0, t1):
        pass
    assert 0.45 <= lag.starved(t0, t1) <= t1 - t0
    assert lag.total(t1) >= lag.starved(t0, t1)


class _Probe(HostLag):
    """A probe whose records the test writes (its thread counts as running)."""

    def __init__(self, times: list[float], totals: list[float]) -> None:
        super().__init__(period_s=0.01, grace_s=0.01)
        self._times, self._totals = times, totals
        self._thread = threading.current_thread()


def test_the_stall_is_placed_at_the_end_of_the_late_sleep_and_a_stall_in_progress_counts():
    # woke at 10.00, then 0.51 s later (0.49 s late beyond sleep and grace), then on time
    probe = _Probe([10.0, 10.52, 10.53], [0.0, 0.49, 0.49])
    assert probe.starved(10.0, 10.53) == pytest.approx(0.49)
    assert probe.starved(10.0, 10.03) == pytest.approx(0.0)  # before the stall began
    assert probe.starved(10.28, 10.52) == pytest.approx(0.24)
    assert probe.starved(10.53, 10.55) == pytest.approx(0.0)  # not yet overdue
    assert probe.starved(10.53, 11.05) == pytest.approx(0.50)  # overdue: a stall going on
    assert probe.starved(10.6, 10.5) == 0.0
    assert probe.starved(0.0, 10.53) == pytest.approx(0.49)  # before the records: from them


LIMITS = SafetyLimits(watchdog_s=4.0, silent_after_s=0.3)


@contextmanager
def _boards_frozen(mock, seconds: float):
    """Only the simulated boards stop (their loop takes this lock every tick), while this
    process runs on: the boards are silent."""
    with mock._lock:
        time.sleep(seconds)
        yield


def test_a_stall_of_the_host_is_not_a_silent_board():
    with open_arm("virtual", "two-link-4-muscle", limits=LIMITS) as (driver, _):
        driver.command("tension", 40.0)
        driver.dwell(0.1)
        with stalled(1.0):
            pass
        assert np.isfinite(driver.read_state(timeout=0.0).tension).all()
        assert np.isfinite(driver.dwell(0.2).tension).all()


def test_boards_silent_while_the_host_runs_are_silent():
    with open_arm("virtual", "two-link-4-muscle", limits=LIMITS) as (driver, mock):
        driver.dwell(0.1)
        with _boards_frozen(mock, 0.8):
            with pytest.raises(BoardSilent, match=r"no status for 0\.\d\d s"):
                driver.read_state(timeout=0.0)


def test_a_board_silent_far_beyond_the_limit_is_named_however_long_the_host_stalled(
        monkeypatch):
    monkeypatch.setattr(driver_module, "SILENT_WHATEVER_THE_LOAD", 2.0)
    with open_arm("virtual", "two-link-4-muscle", limits=LIMITS) as (driver, mock):
        driver.dwell(0.1)
        with _boards_frozen(mock, 0.1):
            with stalled(0.8):  # beyond 2 x the limit, all of it a stall of the host
                pass
            with pytest.raises(BoardSilent, match=r"no status for (0\.9|1\.)\d* s \(limit"):
                driver.read_state(timeout=0.0)


@pytest.mark.parametrize("host", ["stalled", "idle"])
def test_the_simulated_boards_watchdog_does_not_count_a_stall_of_the_host(host):
    """The simulated boards run in this process: while it cannot run their clock stands
    still, so their watchdog relaxes the arm only for a host that stopped commanding while
    it could run."""
    with open_arm("virtual", "two-link-4-muscle",
                  limits=SafetyLimits(watchdog_s=0.5, silent_after_s=0.5)) as (driver, mock):
        driver.command("tension", 40.0)
        driver.dwell(0.1)
        if host == "stalled":  # no command for three watchdog periods, none of it runnable
            with stalled(1.5):
                pass
            driver.read_state()
            assert mock.snapshot().modes == ("tension",) * 4
        else:  # the host simply stopped commanding
            time.sleep(1.5)
            with pytest.raises(WatchdogExpired):
                driver.read_state()


def test_one_probe_serves_the_process():
    assert host_lag() is host_lag()
    with open_arm("virtual", "two-link-4-muscle", limits=LIMITS) as (driver, mock):
        assert driver.host_lag is mock.host_lag is host_lag()
    names = [t.name for t in threading.enumerate()]
    assert names.count("pimbs-host-lag") == 1


class _FullBuffer:
    """A byte stream whose write blocks out its timeout, as a full USB-serial buffer does;
    ``stall`` says whether this program could run meanwhile."""

    def __init__(self, stall: bool) -> None:
        self.stall = stall

    def read(self, n: int) -> bytes:
        time.sleep(0.02)
        return b""

    def write(self, data: bytes) -> int:
        import serial

        if self.stall:
            with stalled(0.6):
                pass
        else:
            time.sleep(0.6)
        raise serial.SerialTimeoutException("Write timeout")

    def close(self) -> None:
        pass


@pytest.mark.parametrize("stall", [True, False])
def test_a_write_that_times_out_while_the_host_stalled_is_no_lost_link(stall):
    from pimbs_hw.safety import LinkLost
    from pimbs_hw.transport import SerialTransport

    transport = SerialTransport(_FullBuffer(stall), name="test")
    try:
        if stall:  # the frame is lost; the link is not
            transport.send(0x101, b"\x01")
            transport.check()
        else:
            with pytest.raises(LinkLost, match="serial write failed: Write timeout"):
                transport.send(0x101, b"\x01")
    finally:
        transport.close()


@pytest.mark.parametrize("stall", [True, False])
def test_a_can_send_that_times_out_while_the_host_stalled_is_no_lost_link(stall, monkeypatch):
    import can

    from pimbs_hw.safety import LinkLost
    from pimbs_hw.transport import CanTransport
    from pimbs_hw.transport.canbus import SEND_TIMEOUT_S

    transport = CanTransport(f"virtual:stall-{stall}-{time.monotonic_ns()}")

    def send(msg, timeout=None):
        if stall:
            with stalled(SEND_TIMEOUT_S + 0.1):
                pass
        else:
            time.sleep(SEND_TIMEOUT_S + 0.1)
        raise can.CanOperationError("Transmit buffer full")

    monkeypatch.setattr(transport.bus, "send", send)
    try:
        if stall:
            transport.send(0x101, b"\x01")
            transport.check()
        else:
            with pytest.raises(LinkLost, match="CAN send failed"):
                transport.send(0x101, b"\x01")
    finally:
        transport.close()
