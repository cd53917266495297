"""What one training run is (data, loss, seed, options) and what it produces.

Shared by the fast trainer and the reference so that both consume and report exactly the
same things, and the benchmark can compare them field by field.

Selection rule (paper; with the automatic physics weight the profiled likelihood of lengths
and torques replaces L_basic, see ``objective.selection_score``): the model kept is the one
of the epoch with the lowest *training*
L_basic (first such epoch on ties); its L_eval is the reported ``eval_loss``. "Epoch e" means
the weights before the e-th optimiser step, i.e. the weights that produced that epoch's loss.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch

from pimbs_learn.data import LearnError, Samples
from pimbs_learn.graph import MLP, SERIES_ELASTIC, STRUCTURES
from pimbs_learn.losses import REPORT_SCALE, LossConfig
from pimbs_learn.model import HIDDEN, Scaling

Progress = Callable[[int], None]  # called with the number of epochs done


@dataclass(frozen=True)
class Run:
    """One training run: its training/evaluation samples, loss, seed and map type."""

    train: Samples
    eval: Samples
    loss: LossConfig = LossConfig()
    seed: int = 0
    atl: bool = True
    structure: str = MLP  # see pimbs_learn.graph
    # constants of the geometric model (pimbs_learn.prior) when it is the prior:
    # l = h_geom(θ) + learned correction; None: no prior
    prior: dict[str, np.ndarray] | None = field(default=None, compare=False)
    prior_robot: str | None = None
    # the torque noise (N·m rms) the evidence of the training rows supports, when already
    # estimated (the self-check estimates it once for all its folds); None: estimate it
    torque_noise: float | None = field(default=None, compare=False)

    @property
    def map_name(self) -> str:
        return "atl" if self.atl else "al"

    @property
    def sensor_terms_apply(self) -> bool:
        """Can the torque balance carry sensor terms: the pinn loss with the automatic
        weight, on an ATL-Map (tensions measured) without a geometric prior (whose own Gᵀf
        they would have to correct too)."""
        return (self.loss.pinn and self.loss.weighting == "auto" and self.atl
                and self.prior is None)

    @property
    def network_inputs_tension(self) -> bool:
        """Does the MLP itself take f (the paper's ATL-Map), or only θ?"""
        return self.atl and self.structure == MLP

    def check(self) -> None:
        """Refuse runs that cannot train meaningfully, before spending any time."""
        if self.train.n_samples < 1 or self.eval.n_samples < 1:
            raise LearnError("training and evaluation sets must each hold at least one sample")
        if self.train.joints != self.eval.joints or self.train.muscles != self.eval.muscles:
            raise LearnError("training and evaluation samples come from different bodies")
        if self.structure not in STRUCTURES:
            raise LearnError(f"unknown structure {self.structure!r}: one of {STRUCTURES}")
        if self.structure == SERIES_ELASTIC and not self.atl:
            raise LearnError("the series-elastic structure is an ATL-Map (it needs tension)")
        if self.loss.pinn and not np.isfinite(self.train.tau).all():
            raise LearnError("the PINN loss needs tau_gravity for every training sample")
        if self.loss.sensors and not self.sensor_terms_apply:
            raise LearnError("sensor terms need the pinn loss with the automatic weight, on "
                             "an ATL-Map without a geometric prior (pimbs train: --no-prior)")

    def residual(self) -> Run:
        """The run the network learns: with a prior, lengths minus the model's and τ plus
        G_geomᵀf (so −(G_geom + ∂r/∂θ)ᵀf = τ is −(∂r/∂θ)ᵀf = τ + G_geomᵀf); else itself."""
        if self.prior is None:
            return self
        from pimbs_learn.prior import GeometricPrior

        geo = GeometricPrior.from_numpy(self.prior)

        def minus_prior(s: Samples) -> Samples:
            with torch.no_grad():
                h, g = (t.numpy() for t in geo(torch.from_numpy(s.theta),
                                                torch.from_numpy(s.tension)))
            return replace(s, length=s.length - h,
                           tau=s.tau + np.einsum("bmn,bm->bn", g, s.tension))

        return replace(self, train=minus_prior(self.train), eval=minus_prior(self.eval))

    def scaling(self) -> Scaling:
        t = self.train
        return Scaling.from_data(t.theta, t.tension if self.atl else None, t.length)


# Learning-rate schedules. "exp" decays lr geometrically to 1 % over the run. Why: Adam
# moves every weight by about lr per step however small its gradient, so at a constant lr a
# network that already interpolates its few samples keeps jumping (training L_basic spikes
# between 1e-9 and 1e-4) and its function between the samples drifts; with 10 samples the
# held-out error of the 1000-1000 network grew 3–20× after its minimum (learning notebook).
# "constant" is the paper's Adam; "cosine" was tried and is worse (its long high-lr middle).
SCHEDULES = ("exp", "constant", "cosine")
EXP_FINAL = 0.01  # lr at the last epoch, relative to the first ("exp")


@dataclass(frozen=True)
class TrainOptions:
    epochs: int = 20000
    lr: float = 1e-3
    hidden: int = HIDDEN
    device: str = "cpu"
    curve_every: int = 0  # record L_eval every k epochs for plots (0: no curve)
    dtype: torch.dtype = torch.float32
    schedule: str = "constant"  # learning rate over the run, one of SCHEDULES
    # networks averaged into the model (pimbs_learn.ensemble); `train` trains them stacked
    members: int = 1

    def lr_at(self, epoch: int) -> float:
        """The learning rate of an epoch under the schedule."""
        t = epoch / self.epochs
        if self.schedule == "exp":
            return self.lr * EXP_FINAL ** t
        if self.schedule == "cosine":
            return self.lr * 0.5 * (1.0 + math.cos(math.pi * t))
        return self.lr

    def torch_device(self) -> torch.device:
        if self.epochs < 1:
            raise LearnError(f"--epochs must be ≥ 1, got {self.epochs}")
        if self.lr <= 0:
            raise LearnError(f"--lr must be > 0, got {self.lr}")
        if self.schedule not in SCHEDULES:
            raise LearnError(f"--lr-schedule must be one of {', '.join(SCHEDULES)}, "
                             f"got {self.schedule!r}")
        dev = torch.device(self.device)
        if dev.type == "cuda" and not torch.cuda.is_available():
            raise LearnError("--device cuda asked for, but torch sees no CUDA device")
        return dev


@dataclass
class TrainResult:
    """Outcome of one run. Losses are raw (m²); ``metrics()`` reports them ×1e5."""

    run: Run
    params: dict[str, np.ndarray]  # weights of the selected (best) epoch, float32
    scaling: Scaling
    best_epoch: int
    train_loss: float  # L_basic on the training set at best_epoch
    eval_loss: float  # L_eval at best_epoch
    epochs: int
    seconds: float
    schedule: str = "constant"  # the learning-rate schedule it was trained with
    # torque noise (N·m rms) the evidence supports, the floor of the automatic weight
    torque_noise_rms: float | None = None
    curve_epochs: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    curve_eval: np.ndarray = field(default_factory=lambda: np.zeros(0))
    curve_train: np.ndarray = field(default_factory=lambda: np.zeros(0))  # L_basic, same epochs
    # the self-check that chose this run's loss (pimbs_learn.selfcheck), and the loss asked
    # for when the check fell back to Basic; None without a check
    self_check: Any = None
    asked_loss: LossConfig | None = None
    # the loadcell and gravity corrections the torque balance fitted (pimbs_learn.sensor_terms)
    sensor_terms: dict[str, list[float]] | None = None
    # the networks averaged into this one (pimbs_learn.ensemble): seed, loss, best epoch and
    # L_eval (m²) of each; None for a single network
    members: list[dict[str, Any]] | None = None

    def metrics(self) -> dict[str, Any]:
        return {
            "eval_loss": self.eval_loss * REPORT_SCALE,
            "train_loss": self.train_loss * REPORT_SCALE,
            "loss_scale": REPORT_SCALE,
            "loss_definition": "mean over samples and muscles of (l_pred - l_data)^2 [m^2]",
            "best_epoch": self.best_epoch,
            "epochs": self.epochs,
            "lr_schedule": self.schedule,
            "torque_noise_rms": self.torque_noise_rms,
            "seconds": self.seconds,
            "n_train": self.run.train.n_samples,
            "n_eval": self.run.eval.n_samples,
            "loss": self.run.loss.name,
            "loss_asked": (self.asked_loss or self.run.loss).name,
            "self_check": None if self.self_check is None else self.self_check.metrics(),
            "alpha": self.run.loss.alpha,
            "weighting": self.run.loss.weighting,
            "sensor_terms": self.sensor_terms,
            "structure": self.run.structure,
            "prior": self.run.prior_robot,
            "map": self.run.map_name,
            "seed": self.run.seed,
            "members": None if self.members is None else [
                {**m, "eval_loss": m["eval_loss"] * REPORT_SCALE} for m in self.members],
        }


def as_tensor(a: np.ndarray, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=device)
