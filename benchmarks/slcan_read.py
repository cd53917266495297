"""Host CPU per received frame over an SLCAN adapter: python-can's reader against ``SlcanBus``.

An emulated SLCAN adapter (``pimbs_hw.mock.slcan``) runs in a child process and sends
8-byte frames to the host over a pty; the host (this process) receives them with
``bus.recv`` and nothing else. Three measurements per reader:

- flood: the adapter sends as fast as the host takes them (the pty is flow-controlled):
  frames per second and host CPU microseconds per frame;
- paced: four ODrive axes' worth of frames (880 frames/s: encoder estimates and torques
  every 10 ms, temperature and heartbeat every 100 ms, as the ``odrive-cansimple`` profile
  has them configured; in bursts every 10 ms) for a few seconds: the share of one core the
  host spends receiving them;
- idle: nothing arrives: the share of a core that waiting costs (python-can polls the port
  every millisecond, its default port timeout; both are asked the same way, ``recv(0.05)``).

Also the adapter process's own CPU per frame (flood), and the host's CPU per sent frame
(python-can's ``send``, which ``SlcanBus`` keeps) with one write timeout and with two
alternating (a thread sending SYNC without a timeout beside the control loop's sends with
one: pyserial reconfigures the port whenever the timeout changes).

    .venv/bin/python benchmarks/slcan_read.py            # 20000 frames flood, 3 s paced
    .venv/bin/python benchmarks/slcan_read.py --frames 5000 --paced-s 2 --repeat 1
    .venv/bin/python benchmarks/slcan_read.py --readme   # and the README's block

CPU times are ``time.process_time`` (this process, every thread), so other load on the
machine changes them less than wall time; say how loaded the machine was when quoting them.
"""

from __future__ import annotations

import argparse
import functools
import multiprocessing as mp
import os
import statistics
import sys
import time

import can
from can.interfaces.slcan import slcanBus

from pimbs_hw.transport.slcan import SlcanBus

README_BLOCK = True
READERS = {"python-can slcanBus": slcanBus, "pimbs SlcanBus": SlcanBus}
DATA = bytes(range(8))


def _adapter(conn, frames: int, rate: float) -> None:
    """Child process: an emulated adapter that sends ``frames`` frames once the host opens
    the channel, as fast as it can (``rate`` 0) or ``rate`` per second in 10 ms bursts."""
    from pimbs_hw.mock.slcan import SlcanAdapter

    adapter = SlcanAdapter()
    conn.send(adapter.port.split(":", 1)[1])
    while not adapter.is_open:
        time.sleep(0.001)
    conn.recv()  # the host is ready
    cpu0 = time.process_time()
    t0 = time.monotonic()
    burst = max(1, round(rate * 0.01) if rate else frames)
    for k in range(0, frames, burst):
        for i in range(k, min(frames, k + burst)):
            adapter.send(0x009 + (i % 4) * 0x20, DATA)
        if rate:
            time.sleep(max(0.0, t0 + (k + burst) / rate - time.monotonic()))
    conn.send(time.process_time() - cpu0)
    conn.recv()  # keep the pty open until the host has read everything
    adapter.close()


def receive(reader: type[slcanBus], frames: int, rate: float = 0.0) -> dict[str, float]:
    """Run one adapter child, receive its frames with ``reader``; times and counts."""
    here, there = mp.Pipe()
    child = mp.Process(target=_adapter, args=(there, frames, rate), daemon=True)
    child.start()
    path = here.recv()
    bus = reader(path, sleep_after_open=0)
    try:
        here.send("go")
        got, cpu0, t0 = 0, time.process_time(), time.monotonic()
        deadline = t0 + 30 + (frames / rate if rate else 0)
        while got < frames and time.monotonic() < deadline:
            if bus.recv(0.1) is not None:
                got += 1
        wall, cpu = time.monotonic() - t0, time.process_time() - cpu0
        adapter_cpu = here.recv()
    finally:
        bus.shutdown()  # before the adapter goes: the host's close command must reach it
        here.send("done")
        child.join(5)
    return {"frames": got, "wall": wall, "cpu": cpu, "adapter_cpu": adapter_cpu}


def idle(reader: type[slcanBus], seconds: float) -> float:
    """Share of a core that ``reader`` spends waiting on a silent adapter."""
    here, there = mp.Pipe()
    child = mp.Process(target=_adapter, args=(there, 0, 0.0), daemon=True)
    child.start()
    bus = reader(here.recv(), sleep_after_open=0)
    try:
        here.send("go")
        here.recv()
        cpu0, t0 = time.process_time(), time.monotonic()
        while time.monotonic() - t0 < seconds:
            bus.recv(0.05)  # as the Notifier thread waits
        share = (time.process_time() - cpu0) / (time.monotonic() - t0)
    finally:
        bus.shutdown()
        here.send("done")
        child.join(5)
    return share


def send_cost(frames: int, alternate: bool) -> float:
    """Host CPU microseconds per sent frame (python-can's send, unchanged by SlcanBus)."""
    from pimbs_hw.mock.slcan import SlcanAdapter

    adapter = SlcanAdapter()  # in this process: its reader's CPU counts too, the same each way
    bus = SlcanBus(adapter.port.split(":", 1)[1], sleep_after_open=0)
    try:
        msg = can.Message(arbitration_id=0x080, data=b"", is_extended_id=False)
        cpu0 = time.process_time()
        for i in range(frames):
            bus.send(msg, timeout=None if alternate and i % 2 else 0.5)
        return (time.process_time() - cpu0) / frames * 1e6
    finally:
        bus.shutdown()
        adapter.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20000, help="frames per flood run")
    ap.add_argument("--paced-s", type=float, default=3.0, help="seconds of the paced run")
    ap.add_argument("--rate", type=float, default=880.0, help="paced frames per second")
    ap.add_argument("--repeat", type=int, default=3, help="runs per reader (median quoted)")
    ap.add_argument("--readme", action="store_true", help="print the README block at the end")
    args = ap.parse_args()
    # with --readme stdout is the block alone (benchmarks/readme_numbers.py pastes it)
    say = functools.partial(print, file=sys.stderr if args.readme else sys.stdout)
    load = os.getloadavg()[0]
    say(f"load average {load:.1f} on {os.cpu_count()} CPUs")
    med = statistics.median
    rows = {}
    for name, reader in READERS.items():
        flood = [receive(reader, args.frames) for _ in range(args.repeat)]
        paced = [receive(reader, round(args.rate * args.paced_s), args.rate)
                 for _ in range(args.repeat)]
        row = rows[name] = {
            "rate": med(r["frames"] / r["wall"] for r in flood),
            "us": med(r["cpu"] / r["frames"] * 1e6 for r in flood),
            "adapter_us": med(r["adapter_cpu"] / args.frames * 1e6 for r in flood),
            "paced": med(r["cpu"] / r["wall"] for r in paced),
            "paced_frames": med(r["frames"] for r in paced),
            "idle": med(idle(reader, 2.0) for _ in range(args.repeat))}
        short = sum(r["frames"] < args.frames for r in flood)
        shorts = f", {short} runs short" if short else ""
        say(f"{name}: flood {row['rate']:.0f} frames/s, {row['us']:.0f} us host CPU per "
              f"frame (adapter {row['adapter_us']:.0f} us){shorts}"
              f"; paced {args.rate:g}/s: {row['paced']:.1%} of a core "
              f"({row['paced_frames']:.0f} of {round(args.rate * args.paced_s)} frames); "
              f"idle: {row['idle']:.1%} of a core")
    for alternate in (False, True):
        us = med(send_cost(args.frames // 4, alternate) for _ in range(args.repeat))
        say(f"send ({'timeouts alternating' if alternate else 'one timeout'}): {us:.0f} us "
              f"host CPU per frame (sender and the emulated adapter's reader)")
    if args.readme:
        theirs, ours = rows["python-can slcanBus"], rows["pimbs SlcanBus"]
        pct = lambda share: f"{share * 100:.0f} %"  # noqa: E731
        print(f"**SLCAN reception** (`.venv/bin/python benchmarks/slcan_read.py`: an emulated "
              f"adapter in another\nprocess sends 8-byte frames over a pty; CPU time of the "
              f"receiving process, median of {args.repeat}\nruns, load average {load:.0f} on "
              f"{os.cpu_count()} cores): python-can's `slcan` reader {theirs['us']:.0f} µs per "
              f"frame, at most\n{theirs['rate']:.0f} frames/s; PIMBS's bulk reader "
              f"{ours['us']:.0f} µs, {ours['rate']:.0f} frames/s. Four ODrive axes "
              f"({args.rate:g} frames/s)\ntake {pct(theirs['paced'])} of a core with "
              f"python-can's reader and {pct(ours['paced'])} with PIMBS's; waiting on an idle "
              f"bus\n{pct(theirs['idle'])} and {pct(ours['idle'])}.")


if __name__ == "__main__":
    main()
