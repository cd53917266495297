"""Does the physics pay on *this* recording? A check from the training rows alone.

Why: the torque balance helps a body schema only where the recorded torques are right. On
an arm whose loadcells read through friction, or whose gravity model is off, the physics
term fits slopes to wrong torques, and with 5–30 samples nothing in the training loss says
so: a large network interpolates wrong torques as easily as right ones. What does say so
is prediction at poses not trained on. The check asks it of a model that must explain
lengths and torques together and pays for flexibility — the Gaussian process of
:mod:`pimbs_learn.noise`, whose evidence the automatic physics weight already uses: leave
each training sample out in turn and predict its lengths from the other samples, once
with their torques and once from their lengths alone. Where the torques, as recorded,
make those predictions better, the physics is kept; otherwise the run falls back to Basic
(the same structure, schedule and width, no physics terms), which is then exactly what
``--loss basic`` would have trained.

The Gaussian process is fitted once per run anyway (the torque noise floor), and its
leave-one-out errors are closed-form, so the check costs no training.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from pimbs_learn.losses import BASIC
from pimbs_learn.noise import NoiseEstimate, noise_of
from pimbs_learn.run import Progress, Run, TrainOptions, TrainResult

# The physics is kept when the torques bring the pooled leave-one-out length error below
# this share of the error without them. One threshold per training-set size, chosen on the
# development half of a population of drawn arms (docs/learning-notebook.md §10): the
# safety bars first (worse than Basic by 5 % on at most a tenth of the arms, never by
# half), then the lowest median ratio to Basic. The Gaussian process's verdict from a few
# samples is noisy, so at small N a ratio somewhat above 1 is no evidence against the
# physics. At 5 samples keeping the physics whatever the check says scored best within
# the safety bars (there the automatic weight's evidence floor is what backs the physics
# off). A run uses the threshold of the nearest size (between two, the lower).
KEEP_BELOW = {5: float("inf"), 10: 1.5, 30: 1.2}


def keep_below(n_train: int) -> float:
    """The threshold for a run of ``n_train`` training samples."""
    gap = min(abs(n_train - n) for n in KEEP_BELOW)
    return min(t for n, t in KEEP_BELOW.items() if abs(n_train - n) == gap)


@dataclass(frozen=True)
class SelfCheck:
    """Leave-one-sample-out length errors of the training rows, with and without torques."""

    samples: int  # training samples the check used (subsampled beyond the GP's cap)
    with_torque: float  # pooled squared length error, scaled units
    without_torque: float
    torque_noise_rms: float  # N·m, the evidence's torque noise (the physics weight's floor)
    keep_below: float  # the threshold of this run's training-set size

    @property
    def ratio(self) -> float:
        return self.with_torque / self.without_torque if self.without_torque > 0 else np.inf

    @property
    def keeps_physics(self) -> bool:
        return bool(self.ratio < self.keep_below)

    def line(self, loss: str) -> str:
        """One line for ``pimbs train``'s output."""
        verdict = (f"kept ({loss})" if self.keeps_physics
                   else "not shown to help, so trained without it (basic)")
        rule = ("kept whatever the ratio at this many samples" if np.isinf(self.keep_below)
                else f"kept below ×{self.keep_below:g} at this many samples")
        return (f"self-check, each of {self.samples} training samples predicted from the "
                f"others: the torques change the length error ×{self.ratio:.2f} ({rule}); "
                f"physics {verdict}")

    def metrics(self) -> dict:
        return {"method": "gaussian-process leave-one-sample-out", "samples": self.samples,
                "with_torque": self.with_torque, "without_torque": self.without_torque,
                "ratio": self.ratio,
                # null where the physics is kept whatever the ratio (JSON has no infinity)
                "keep_below": None if np.isinf(self.keep_below) else self.keep_below,
                "physics_kept": self.keeps_physics}

    @classmethod
    def from_estimate(cls, e: NoiseEstimate, threshold: float) -> SelfCheck:
        assert e.loo_with_torque is not None and e.loo_without_torque is not None
        return cls(samples=len(e.loo_with_torque), with_torque=float(e.loo_with_torque.sum()),
                   without_torque=float(e.loo_without_torque.sum()),
                   torque_noise_rms=e.torque_rms, keep_below=threshold)


def applies(run: Run) -> bool:
    """The check decides for runs with the physics terms and at least three samples."""
    return run.loss.pinn and run.train.n_samples >= 3 and run.train.has_tau


def self_check(run: Run, threshold: float | None = None) -> SelfCheck | None:
    """The check on ``run``'s training rows (with a prior: on what the network learns), or
    None where the sample set is degenerate for the Gaussian process. ``threshold``:
    :func:`keep_below` of the run's training rows unless given."""
    e = noise_of(run.residual().train, run.seed, run.loss.sensors)
    if e is None:
        return None
    return SelfCheck.from_estimate(
        e, keep_below(run.train.n_samples) if threshold is None else threshold)


def train_checked(run: Run, options: TrainOptions | None = None,
                  progress: Progress | None = None) -> TrainResult:
    """Self-check, then train with the loss it chose (the physics terms or Basic)."""
    from pimbs_learn.train import train

    t0 = time.perf_counter()
    check = self_check(run) if applies(run) else None
    if check is None:
        return train(run, options, progress)
    final = run if check.keeps_physics else replace(run, loss=BASIC)
    # the weight's floor is the same evidence: no second fit
    final = replace(final, torque_noise=check.torque_noise_rms)
    result = train(final, options, progress)
    return replace(result, self_check=check, asked_loss=run.loss,
                   seconds=time.perf_counter() - t0)
