"""The types of the paper's tables: a method (one row), a table's specification and its
results. Both the experiment that fills them and the figures that draw them import these, so
neither imports the other."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pimbs_learn.graph import MLP, SERIES_ELASTIC
from pimbs_learn.losses import REPORT_SCALE, LossConfig
from pimbs_learn.run import TrainResult

TWO_LINK, FIVE_DOF = "two-link-4-muscle", "left-arm-5dof"
PAPER_LOSSES = ("basic", "basic+const", "basic+pinn", "basic+const+pinn")


@dataclass(frozen=True)
class Method:
    """One row of a table: a loss, its α (or automatic weighting), structure and prior."""

    loss: str
    alpha: float = 1e-5
    structure: str = MLP
    weighting: str = "fixed"
    prior: bool = False
    schedule: str = "constant"  # learning-rate schedule (TrainOptions.schedule)

    @property
    def label(self) -> str:
        name = "+".join(t.capitalize() if t != "pinn" else "PINN" for t in self.loss.split("+"))
        if self.structure == SERIES_ELASTIC:
            name = "SE " + name
        if "pinn" in self.loss:
            name += " (auto α)" if self.weighting == "auto" else f" (α={self.alpha:g})"
        if self.schedule != "constant":
            name += f", lr {self.schedule}"
        return name + (" + prior" if self.prior else "")

    def config(self) -> LossConfig:
        return LossConfig.parse(self.loss, self.alpha if self.weighting == "fixed" else 1.0,
                                self.weighting)


# The new default of `pimbs train` (without and with the robot description as prior).
DEFAULT = Method("basic+const+pinn", structure=SERIES_ELASTIC, weighting="auto",
                 schedule="exp")
DEFAULT_PRIOR = replace(DEFAULT, prior=True)
# the paper's Basic with the default's learning-rate schedule: what the schedule alone does
BASIC_EXP = Method("basic", schedule="exp")


@dataclass(frozen=True)
class TableSpec:
    key: str
    title: str
    robot: str
    atl: bool
    n_train: tuple[int, ...]
    methods: tuple[Method, ...]
    pool: int  # rows of the training recording (Tables I/II) or of the whole recording (III)
    eval_samples: int | None  # separate D_eval size, or None: the rest of the recording
    noise: float


@dataclass
class TableResult:
    spec: TableSpec
    results: dict[tuple[str, int], list[TrainResult]]  # (method label, N) -> one per seed

    def cell(self, label: str, n: int) -> tuple[float, float]:
        v = np.array([r.eval_loss for r in self.results[(label, n)]]) * REPORT_SCALE
        return float(v.mean()), float(v.std())
