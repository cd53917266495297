"""Encoder zeroing at the home pose: the measurement ``pimbs zero`` makes through the
driver. What it yields is kept as data in the robot's calibration file
(``pimbs_calibration.zeroing``).

Incremental encoders power up anywhere; the recording format needs lengths relative to the
zero pose, ``l(θ = 0, f = 0) = 0``. Each motor encoder is read while the arm is held at
θ = 0 with the wires at their low holding tension, and what that tension stretches the
elastic element (``Δn(f) = log1p(f) / K``, the arm model's own law) is removed, so the zero
is the slack-wire length without ever letting a wire go slack.
"""

from __future__ import annotations

import numpy as np


def measure_zero(driver, model, seconds: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Relax at the home pose, average the readings; (zero position m, mean tension N)."""
    driver.zero_m[:] = 0.0  # raw encoder readings from here on
    driver.relax()
    driver.dwell(0.3)  # let the wires settle at their holding floor
    positions, tensions = [], []
    end = seconds
    while end > 0:
        state = driver.dwell(0.05)
        positions.append(state.length)
        tensions.append(state.tension)
        end -= 0.05
    position, tension = np.mean(positions, axis=0), np.mean(tensions, axis=0)
    # at theta = 0: l = h_geom(0) - dn(f) with h_geom(0) = 0, so the slack-wire zero is
    # the reading plus the stretch the holding tension causes
    return position + model.stretch(np.maximum(tension, 0.0)), tension
