"""Winding-direction check: pull each muscle gently, one at a time, and watch what it does.

The rule (docs/boards.md): a muscle's ``direction`` is +1 when a positive motor turn reels
its wire in. Pulling a correctly wired muscle raises its tension while its length
shortens, then the motor stops against the wire. What a wrong sign looks like depends on
where the tension comes from, and every case is caught:

- the tension is measured apart from the motor (a loadcell: PIMBS v1, most lab boards): the
  tension rises but the length reading grows (the encoder counts the wrong way);
- the tension is the motor's own torque (ODrive): the motor turns the wrong way round the
  pulley and pays the wire out, so nothing holds it: the length runs on under a gentle
  torque and the torque the wire puts on the rotor stays near zero.

Only one muscle is pulled at a time, to a gentle tension, and every muscle is relaxed to its
holding floor between pulls and at the end; the driver's limits stay in force throughout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FREE_RUN_M_S = 0.005  # a wire still moving faster than this after settling is not held
SETTLE_S, WATCH_S = 0.6, 0.2


@dataclass(frozen=True)
class WiringCheck:
    """One muscle's pull: what its readings did, and the verdict in one line."""

    muscle: str
    ok: bool
    pull_n: float  # the tension asked above the holding floor, N
    d_tension: float  # N, reading after the pull minus before
    d_length: float  # m, same
    speed: float  # m/s, the length's speed at the end of the pull (0 = held)
    line: str


def gentle_pull(f_floor: float, f_max: float) -> float:
    """Tension step of the check: a tenth of the range, at most 20 N, at least 2 N."""
    return float(np.clip(0.1 * (f_max - f_floor), 2.0, 20.0))


def _verdict(name: str, pull: float, d_f: float, d_l: float, speed: float,
             moving_before: float) -> tuple[bool, str]:
    numbers = (f"tension {d_f:+.1f} N, length {1e3 * d_l:+.1f} mm for a {pull:.0f} N pull")
    flip = "flip its `direction` in the robot file (1 <-> -1)"
    if max(speed, moving_before) > FREE_RUN_M_S:
        run = 1e3 * max(speed, moving_before)
        return False, (f"{name}: WRONG SIGN: the length runs on at {run:.0f} mm/s under a "
                       f"gentle torque: the motor pays the wire out instead of reeling it in "
                       f"(held still now); {flip}")
    if d_f < 0.3 * pull:
        return False, (f"{name}: the tension did not rise ({numbers}): check that the wire is on "
                       f"its pulley and the sensor is connected, then the direction")
    if d_l > 0:
        return False, (f"{name}: WRONG SIGN: the tension rose but the length grew ({numbers}); "
                       f"{flip}")
    return True, f"{name}: ok ({numbers})"


def check_wiring(driver, pull_n: float | None = None, settle_s: float = SETTLE_S,
                 watch_s: float = WATCH_S) -> list[WiringCheck]:
    """Pull every muscle of ``driver``'s arm in turn; one ``WiringCheck`` per muscle.

    First every muscle is relaxed and watched: one whose length runs on under the holding
    torque pays its wire out (a torque-driven motor wound the wrong way); it is held where
    it is (a length command holds the rotor still, whatever the sign) and not pulled.
    """
    driver.relax()
    driver.dwell(settle_s)
    first = driver.dwell(watch_s)
    last = driver.dwell(watch_s)
    drift = np.abs(last.length - first.length) / max(last.time - first.time, 1e-3)
    held = drift > FREE_RUN_M_S
    hold_at = last.length.copy()
    base_modes = ["length" if h else "relax" for h in held]

    def settle(modes: list[str], values: np.ndarray, seconds: float):
        driver.command(modes, values)
        return driver.dwell(seconds)

    results = []
    if held.any():
        settle(base_modes, hold_at, watch_s)
    for i, name in enumerate(driver.muscles):
        pull = pull_n if pull_n is not None else gentle_pull(driver.f_floor[i], driver.f_max[i])
        if held[i]:
            ok, line = _verdict(name, pull, 0.0, 0.0, 0.0, float(drift[i]))
            results.append(WiringCheck(name, ok, pull, 0.0, 0.0, float(drift[i]), line))
            continue
        before = settle(base_modes, hold_at, watch_s)
        modes, values = list(base_modes), hold_at.copy()
        modes[i], values[i] = "tension", driver.f_floor[i] + pull
        mid = settle(modes, values, settle_s)
        after = driver.dwell(watch_s)
        speed = abs(after.length[i] - mid.length[i]) / max(after.time - mid.time, 1e-3)
        d_f = float(after.tension[i] - before.tension[i])
        d_l = float(after.length[i] - before.length[i])
        ok, line = _verdict(name, pull, d_f, d_l, speed, 0.0)
        results.append(WiringCheck(name, ok, pull, d_f, d_l, speed, line))
        settle(base_modes, hold_at, settle_s)
    return results
