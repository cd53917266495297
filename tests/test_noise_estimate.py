"""The torque-noise estimate behind the automatic physics weight's floor: it must recover a
known noise level, and grow when the torques disagree with what the lengths imply (the
friction-concealed case), which interpolation of the training samples cannot hide."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from pimbs_learn.data import Samples
from pimbs_learn.losses import LossConfig
from pimbs_learn.noise import estimate_noise
from pimbs_learn.run import Run, TrainOptions
from pimbs_learn.synthetic import synthetic_samples
from pimbs_learn.train import TORQUE_FLOOR, train

torch.set_num_threads(1)


def _samples(n: int, seed: int, tau_noise: float = 0.0, tension_error: float = 0.0
             ) -> Samples:
    """The synthetic body, torques with Gaussian noise of tau_noise N·m rms, and recorded
    tensions off by ±tension_error (relative), the sign a smooth function of the pose: a
    loadcell that does not see the tendon's own tension, as with friction."""
    s = synthetic_samples(n, seed=seed, theta_range=1.0)
    rng = np.random.default_rng(seed + 100)
    sign = np.sign(np.sin(3.0 * s.theta[:, :1] + np.arange(s.tension.shape[1])))
    return replace(s, tau=s.tau + rng.normal(0.0, tau_noise, s.tau.shape),
                   tension=s.tension * np.exp(tension_error * sign))


def _estimate(s: Samples):
    return estimate_noise(s.theta, s.tension, s.length, s.tau)


@pytest.mark.parametrize("seed", [0, 1])
def test_recovers_a_known_torque_noise(seed: int) -> None:
    est = _estimate(_samples(30, seed, tau_noise=0.05))
    assert 0.02 < est.torque_rms < 0.125, est


def test_inconsistent_torques_read_as_torque_noise() -> None:
    """10 % tension errors that vary with the pose: the evidence must call the torques far
    noisier than the same arm's consistent torques, though each set alone is smooth."""
    clean = _estimate(_samples(10, 3, tau_noise=0.01))
    wrong = _estimate(_samples(10, 3, tau_noise=0.01, tension_error=0.1))
    assert wrong.torque_rms > 5 * clean.torque_rms, (clean, wrong)


def test_training_floors_the_torque_variance_at_the_estimate() -> None:
    """The automatic weight's torque floor is the evidence's noise where that is larger than
    the relative floor, so a network that interpolates wrong torques no longer makes α_eff
    grow; fixed-α runs do not estimate anything."""
    auto = LossConfig.parse("basic+const+pinn", 1.0, "auto")
    opts = TrainOptions(epochs=2, hidden=16, dtype=torch.float64)
    ev = synthetic_samples(20, seed=9)
    results = {err: train(Run(_samples(10, 3, 0.01, err), ev, auto, 0, True,
                              "series-elastic"), opts) for err in (0.0, 0.1)}
    tau_max = float(np.abs(_samples(10, 3).tau).max())
    assert results[0.1].torque_noise_rms > 10 * TORQUE_FLOOR * tau_max
    assert results[0.1].torque_noise_rms > 5 * results[0.0].torque_noise_rms
    assert results[0.1].metrics()["torque_noise_rms"] == results[0.1].torque_noise_rms
    fixed = train(Run(_samples(10, 3), ev, LossConfig.parse("basic+pinn", 1e-5), 0, True,
                      "series-elastic"), opts)
    assert fixed.torque_noise_rms is None
