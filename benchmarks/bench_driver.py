"""Arm driver throughput over the python-can virtual bus, and the CAN bus load it implies.

    .venv/bin/python benchmarks/bench_driver.py [--robot left-arm-5dof] [--seconds 3]

One cycle = ``command`` every muscle (one frame per board) + ``read_state`` that waits for a
fresh status frame from every board (the boards answer every command). Prints cycles/s, the
CPU time per cycle of the control thread and of the whole process (which also runs the
simulated boards and their physics), and the load that traffic would put on a 1 Mbit/s CAN bus
(exact bits per frame, bit stuffing included, plus the boards' 50 Hz periodic status).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pimbs_hw import SafetyLimits, open_arm
from pimbs_hw.protocol.busload import bus_load, frame_bits
from pimbs_hw.protocol.codec import Fault, JointStatus, Status, TensionCommand, encode


def _cycle_bits(driver, raw: int) -> tuple[float, float]:
    """Bits of one command + reply round for every board, and of 1 s of periodic frames."""
    per_cycle = sum(frame_bits(*encode(TensionCommand(b, 5, raw)))
                    + frame_bits(*encode(Status(b, 5, 1234, raw, 31.5, Fault(0))))
                    for b in driver.board_ids)
    periodic = 50 * sum(frame_bits(*encode(Status(b, 5, 1234, raw, 31.5, Fault(0))))
                        for b in driver.board_ids)
    periodic += 50 * sum(frame_bits(*encode(JointStatus(j, 5, 0.1234)))
                         for j in range(len(driver._joint_rx)))
    return per_cycle, periodic


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="left-arm-5dof")
    parser.add_argument("--seconds", type=float, default=3.0)
    args = parser.parse_args()
    limits = SafetyLimits(silent_after_s=0.5)
    with open_arm("virtual", args.robot, limits=limits) as (driver, _):
        m = len(driver.muscles)
        tension = np.full(m, 40.0)
        for _ in range(50):  # warm-up: the boards' equilibrium for this command is solved
            driver.command("tension", tension)
            driver.read_state()
        time.sleep(0.2)
        n, stale = 0, 0
        wall0, cpu0, thread0 = time.perf_counter(), time.process_time(), time.thread_time()
        while time.perf_counter() - wall0 < args.seconds:
            driver.command("tension", tension)
            stale += int((~driver.read_state(timeout=0.05).fresh).sum())
            n += 1
        wall = time.perf_counter() - wall0
        cpu, thread = time.process_time() - cpu0, time.thread_time() - thread0
        raw = driver.protocol_of(0).raw(0, tension[0])
        per_cycle, periodic = _cycle_bits(driver, raw)
    rate = n / wall
    load = bus_load(rate * per_cycle + periodic, 1.0)
    max_rate = (1_000_000 - periodic) / per_cycle
    print(f"robot {args.robot}: {m} boards over python-can virtual, {n} cycles in {wall:.2f} s")
    print(f"  driver cycles/s            {rate:8.0f}   ({1e3 / rate:.3f} ms per cycle, "
          f"{stale} stale board reads)")
    print(f"  CPU per cycle, control thread     {1e6 * thread / n:8.0f} us")
    print(f"  CPU per cycle, whole process      {1e6 * cpu / n:8.0f} us  "
          "(driver + receive thread + simulated boards)")
    print(f"  bits per cycle on CAN      {per_cycle:8.0f}   ({m} TENSION + {m} STATUS, stuffed)")
    print(f"  periodic traffic           {periodic / 1e3:8.1f} kbit/s  (50 Hz status + joints)")
    print(f"  bus load at {rate:.0f} cycles/s on 1 Mbit/s: {100 * load:.0f} %"
          + ("  -> the bus, not the host, would limit the rate" if load > 1 else ""))
    print(f"  cycle rate that fills 1 Mbit/s: {max_rate:.0f}/s (70 % load: "
          f"{0.7 * 1_000_000 / per_cycle - periodic / per_cycle:.0f}/s)")


if __name__ == "__main__":
    main()
