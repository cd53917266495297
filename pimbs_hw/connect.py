"""``open_arm``: one call from a ``--port`` string to a running driver (and simulated arm).

    from pimbs_hw import open_arm

    with open_arm("virtual", "two-link-4-muscle", faults=["overheat:m1@40"], seed=1,
                  speed=10) as (driver, mock):
        for i, lengths in enumerate(poses):
            if mock is not None:
                mock.set_sample(i)           # lets @SAMPLE faults trigger at sample i
            driver.command("length", lengths)
            state = driver.dwell(0.3)        # settle while feeding the board watchdogs
    # the arm is relaxed on the way out, whatever happened inside

Ports: ``virtual`` (in-process simulated arm on a fresh python-can virtual channel),
``virtual:NAME`` (same, on channel NAME), ``pty`` (simulated arm behind a pty, driven through
the serial transport), ``slcan-pty`` (simulated arm behind an emulated SLCAN adapter on a
pty, opened through python-can's real ``slcan`` interface); anything else is real hardware
or an external ``pimbs mockbus``
(``can0``, ``pcan:PCAN_USBBUS1``, ``udp_multicast``, ``/dev/ttyACM0``...; see
``pimbs_hw.transport``). ``mock`` is the ``MockArm`` (true state via ``mock.snapshot()``) or
None on hardware. Faults and effects exist only on the simulated arm.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from pimbs_hw.driver import ArmDriver
from pimbs_hw.mock import MockArm
from pimbs_hw.mock.arm import served_in_process
from pimbs_hw.safety import SafetyLimits
from pimbs_hw.transport import open_transport

SIMULATED_PORTS = ("virtual", "pty", "slcan-pty")
# Boards answer their limits within milliseconds; simulated ones share this process's CPU with
# the host (and, behind slcan-pty, an emulated adapter), which on a loaded machine can take
# over a second to come up although nothing is wrong.
CONNECT_TIMEOUT_S, SIMULATED_CONNECT_TIMEOUT_S = 1.0, 5.0
# The simulated boards run in this process: their physics solver competes with the collection
# loop and the boards' own loop for the CPU (and the GIL), so on a loaded machine the loop can
# miss the real boards' 0.25 s watchdog, and a status frame can come 0.3-0.5 s late, although
# nothing hangs (seen with the load average at 10 on 2 cores). Real boards have their own CPU
# and keep the defaults; a silent simulated board is still found, within a second.
SIMULATED_LIMITS = SafetyLimits(watchdog_s=1.0, silent_after_s=1.0)
# The same holds for a board that keeps a watchdog of its own, set in its firmware rather than
# by the host (a profile's ``watchdog``: the lab board's and ODrive's 0.6 s): simulated beside
# the host, it runs with the host's watchdog time where its own is shorter. The boards' clock
# leaves out the stalls of this whole process, not a host loop slowed by sharing a crowded CPU
# and the GIL with the boards' own solver and the emulated adapter: on 2 cores at load 12-16
# the host's commands reached simulated ODrives up to 0.5 s apart on that clock. Real boards
# have their own CPU and keep their firmware's time.
# A send waits for the other end to take the frame (a full USB-serial or SLCAN buffer). An
# adapter or pty served by simulated boards in this process drains only when this process's
# threads get the CPU and the GIL, which on a loaded machine can take longer than the 0.5 s
# that means a lost link on real hardware.
SIMULATED_SEND_TIMEOUT_S = 3.0


def is_simulated(port: str) -> bool:
    return port in SIMULATED_PORTS or port.startswith("virtual:")


def mock_link(port: str) -> str:
    """The link a ``MockArm`` sits on for a simulated ``--port`` (a fresh virtual channel)."""
    if port == "virtual":
        return f"virtual:pimbs-{uuid.uuid4().hex[:12]}"
    return "slcan" if port == "slcan-pty" else port


@contextmanager
def open_arm(port: str = "virtual", robot="two-link-4-muscle", *,
             faults: Sequence[str] | str | None = None, effect=None, seed: int = 0,
             speed: float = 1.0, limits: SafetyLimits | None = None,
             connect_timeout_s: float | None = None, zero_m=None,
             mock_options: dict | None = None, hold_at_start: bool = False
             ) -> Iterator[tuple[ArmDriver, MockArm | None]]:
    """Driver for the arm on ``port``; starts the simulated arm for simulated ports.

    ``zero_m``: encoder readings at the zero pose (from ``pimbs zero``'s calibration file).
    ``mock_options``: extra ``MockArm`` arguments (e.g. ``encoder_offset_m``).
    ``limits``: default ``SafetyLimits()``, or ``SIMULATED_LIMITS`` where the boards are
    simulated in this process. ``connect_timeout_s``: how long the boards have to answer
    (default: 1 s, 5 s simulated). ``hold_at_start``: the motors hold their lengths once the
    boards are configured, instead of relaxing (an arm that would fall when relaxed).
    """
    if isinstance(robot, str | Path):
        from pimbs_calibration.description import load_robot

        robot = load_robot(robot)
    mock = None
    transport_kwargs = {}
    if is_simulated(port) or served_in_process(port):
        limits = SIMULATED_LIMITS if limits is None else limits
        transport_kwargs["send_timeout_s"] = SIMULATED_SEND_TIMEOUT_S
    if connect_timeout_s is None:
        connect_timeout_s = (SIMULATED_CONNECT_TIMEOUT_S if is_simulated(port)
                             else CONNECT_TIMEOUT_S)
    if is_simulated(port):
        if port == "slcan-pty":
            transport_kwargs["sleep_after_open"] = 0  # a pty needs no adapter reset wait
        mock = MockArm(robot, mock_link(port), effect=effect, faults=faults or (), seed=seed,
                       speed=speed, watchdog_floor_s=limits.watchdog_s,
                       **(mock_options or {})).start()
        port = mock.port
    elif faults or effect is not None:
        raise ValueError(f"faults and effects exist only on the simulated arm, not on port "
                         f"{port!r}; use --port virtual")
    try:
        transport = open_transport(port, **transport_kwargs)
        try:
            driver = ArmDriver(transport, robot, limits, connect_timeout_s=connect_timeout_s,
                               hold_at_start=hold_at_start)
        except BaseException:
            transport.close()
            raise
        if zero_m is not None:
            driver.set_zero(zero_m)
        with driver:
            yield driver, mock
    finally:
        if mock is not None:
            mock.stop()
