"""How a simulated arm's boards read it: noise, motor heating, latency and hysteresis.

A recording holds what the sensors said, not the arm's true state. ``SensorModel()`` is the
plain sensor ``pimbs simulate`` has always had (white noise, a motor temperature that rises
with load); the realistic options are off by default, so a default simulation writes the
same bytes as before. Each option, in the units it is given in:

* **noise** (``SensorNoise``): standard deviations of the loadcell (N), motor encoder (m),
  joint angle (rad) and temperature (°C) readings, white, scaled together by ``simulate``'s
  ``noise``.
* **motor temperature** (``ThermalModel``): first order towards ``ambient`` (°C) plus
  ``gain`` (°C per N held) times the tension, with time constant ``time_constant`` (s). The
  motor heats with its load and lags it, so a temperature follows the load history and not
  the pose alone.
* **latency** (``latency_s``, s): the loadcell and the motor encoder are read through a
  first-order filter of time constant ``latency_s``, ``read_after_s`` seconds after the arm
  reached its pose. What is logged is therefore
  ``y_i = x_i + a·(y_{i−1} − x_i)`` with ``a = exp(−read_after_s / latency_s)``: a share
  ``a`` of the previous pose's reading leaks into this one (the arm starts at home,
  unloaded: ``y_{−1} = 0``). 0 (default) reads the settled value.
* **hysteresis** (``hysteresis_n``, N): a loadcell's loading branch lies below its
  unloading branch. A muscle whose tension rose into this pose reads ``f − h``, one whose
  tension fell reads ``f + h`` (a change under ``HYSTERESIS_DEADBAND`` N keeps the previous
  branch; the first pose is reached by loading). 0 (default) has none.

Latency and hysteresis act on the reading after the concealed effects of
:mod:`pimbs_sim.effects` (those describe the loadcell's calibration and the tendon's
friction) and before the white noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

HYSTERESIS_DEADBAND = 0.5  # N: a smaller tension change does not move the loadcell's branch


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviations of the simulated sensors (scaled together by ``scale``)."""

    tension: float = 0.3       # N, loadcell
    length: float = 5e-6       # m, motor encoder
    theta: float = 2e-4        # rad, joint angle estimate
    temperature: float = 0.1   # °C

    def scaled(self, scale: float) -> SensorNoise:
        return SensorNoise(self.tension * scale, self.length * scale, self.theta * scale,
                           self.temperature * scale)


@dataclass(frozen=True)
class ThermalModel:
    """Motor temperature: first order towards ambient + gain·tension."""

    ambient: float = 25.0         # °C
    gain: float = 0.06            # °C per N held
    time_constant: float = 240.0  # s

    def step(self, temp: np.ndarray, tension: np.ndarray, dt: float) -> np.ndarray:
        a = np.exp(-dt / self.time_constant)
        return self.ambient + (temp - self.ambient) * a + (1 - a) * self.gain * tension


@dataclass(frozen=True)
class SensorModel:
    """What the boards' sensors add to the true state (see the module docstring)."""

    noise: SensorNoise = field(default_factory=SensorNoise)
    thermal: ThermalModel = field(default_factory=ThermalModel)
    latency_s: float = 0.0     # s, time constant of the loadcell and encoder filters
    read_after_s: float = 1.0  # s, from reaching the pose to the reading
    hysteresis_n: float = 0.0  # N, half the gap between the loadcell's two branches

    def __post_init__(self) -> None:
        if self.latency_s < 0 or self.read_after_s <= 0 or self.hysteresis_n < 0:
            raise ValueError("latency_s and hysteresis_n must be >= 0 and read_after_s > 0")

    @property
    def leak(self) -> float:
        """Share of the previous reading left in this one (0 without latency)."""
        return float(np.exp(-self.read_after_s / self.latency_s)) if self.latency_s else 0.0

    def to_json(self) -> dict:
        return {"noise": vars(self.noise), "thermal": vars(self.thermal),
                "latency_s": self.latency_s, "read_after_s": self.read_after_s,
                "hysteresis_n": self.hysteresis_n, "leak": self.leak}


class SensorReadout:
    """The stateful part of a ``SensorModel`` over one recording: the filters' memory and
    each loadcell's branch. Call ``read`` once per pose, in collection order."""

    def __init__(self, model: SensorModel, n_muscles: int) -> None:
        self.model = model
        self._tension = np.zeros(n_muscles)  # filter outputs (the previous readings)
        self._length = np.zeros(n_muscles)
        self._true = np.zeros(n_muscles)     # previous true tension (the branch's cause)
        self._branch = np.ones(n_muscles)    # +1 loading, -1 unloading

    def read(self, tension_true: np.ndarray, tension_sensed: np.ndarray,
             length: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(tension, length) as logged, before white noise. ``tension_true`` is the
        joint-side tension (its changes pick the hysteresis branch), ``tension_sensed`` what
        the loadcell's calibration and the tendon's friction make of it."""
        m = self.model
        if not (m.latency_s or m.hysteresis_n):
            return tension_sensed, length
        change = tension_true - self._true
        self._branch = np.where(np.abs(change) > HYSTERESIS_DEADBAND, np.sign(change),
                                self._branch)
        self._true = np.array(tension_true, dtype=float)
        tension = tension_sensed - m.hysteresis_n * self._branch
        a = m.leak
        self._tension = tension + a * (self._tension - tension)
        self._length = length + a * (self._length - length)
        return self._tension.copy(), self._length.copy()
