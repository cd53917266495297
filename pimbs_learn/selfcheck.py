"""Does the physics pay on *this* recording? A check from the training rows alone.

Why: the torque balance helps a body schema only where the recorded torques are right. On
an arm whose loadcells read through friction, or whose gravity model is off, the physics
term fits slopes to wrong torques, and with 5–30 samples nothing in the training loss says
so. What does say so is prediction at poses not trained on: train the schema with and
without the physics terms on K folds of the training rows, and compare their errors on the
rows each fold left out. The physics is kept only when it predicted the left-out lengths
better; otherwise the run falls back to Basic (the same structure, schedule and width, no
physics), which is then exactly what ``--loss basic`` would have trained.

The 2K fold runs have one shape (every fold leaves out the same number of rows), so they
train together as one stacked batch (:func:`pimbs_learn.train.train_runs`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from pimbs_learn.losses import LossConfig
from pimbs_learn.run import Progress, Run, TrainOptions, TrainResult

FOLDS = 5
BASIC = LossConfig(const=False, pinn=False)
# The physics is kept when its pooled held-out error is below Basic's times this: a tie
# ("cannot tell") falls back, since a default must not hurt where it cannot tell.
KEEP_BELOW = 1.0


@dataclass(frozen=True)
class SelfCheck:
    """Held-out length errors of the fold runs, with and without the physics terms."""

    folds: int
    held_out: int  # rows each fold leaves out
    physics: float  # mean squared held-out length error, m², pooled over folds
    basic: float
    keep_below: float = KEEP_BELOW

    @property
    def ratio(self) -> float:
        return self.physics / self.basic if self.basic > 0 else float("inf")

    @property
    def keeps_physics(self) -> bool:
        return self.ratio < self.keep_below

    def line(self, loss: str) -> str:
        """One line for ``pimbs train``'s output."""
        verdict = (f"kept ({loss})" if self.keeps_physics
                   else "not shown to help, so trained without it (basic)")
        return (f"self-check, {self.folds} folds of the training rows ({self.held_out} "
                f"left out each): held-out length error with the physics terms "
                f"{self.ratio:.2f}× that without; physics {verdict}")

    def metrics(self) -> dict:
        return {"folds": self.folds, "held_out_rows": self.held_out,
                "physics_eval_loss": self.physics, "basic_eval_loss": self.basic,
                "ratio": self.ratio, "keep_below": self.keep_below,
                "physics_kept": self.keeps_physics}


def applies(run: Run) -> bool:
    """The check is meaningful for a run with physics terms and enough rows to fold."""
    return (run.loss.pinn or run.loss.const) and run.train.n_samples >= 3


def fold_runs(run: Run, folds: int = FOLDS) -> tuple[list[Run], list[Run], int]:
    """(physics fold runs, basic fold runs, rows left out per fold).

    The training rows are permuted with the run's seed and cut into ``folds`` blocks of
    ⌊N/folds⌋ rows (at least one); each fold trains on the other rows and evaluates on its
    block. Folds keep the run's seed, so a fold's two runs start from the same weights.
    """
    n = run.train.n_samples
    k = min(folds, n)
    out = max(1, n // k)
    order = np.random.default_rng([run.seed, 17]).permutation(n)
    physics, basic = [], []
    for i in range(k):
        held = np.sort(order[i * out:(i + 1) * out])
        kept = np.setdiff1d(np.arange(n), held)
        fold = replace(run, train=run.train.take(kept), eval=run.train.take(held))
        physics.append(fold)
        basic.append(replace(fold, loss=BASIC))
    return physics, basic, out


def with_noise(run: Run) -> Run:
    """``run`` with the evidence's torque noise estimated once from all its training rows,
    so that its folds and its final training share it instead of each estimating it."""
    if run.torque_noise is not None or not (run.loss.pinn and run.loss.weighting == "auto"):
        return run
    from pimbs_learn.train import torque_noise

    return replace(run, torque_noise=torque_noise(run))


def self_check(run: Run, options: TrainOptions, folds: int = FOLDS,
               progress: Progress | None = None) -> SelfCheck:
    """Train the fold runs (one stacked batch) and compare their held-out errors."""
    from pimbs_learn.train import train_runs

    physics, basic, out = fold_runs(with_noise(run), folds)
    results = train_runs(physics + basic, options, progress)
    k = len(physics)
    return SelfCheck(folds=k, held_out=out,
                     physics=float(np.mean([r.eval_loss for r in results[:k]])),
                     basic=float(np.mean([r.eval_loss for r in results[k:]])))


def train_checked(run: Run, options: TrainOptions | None = None,
                  progress: Progress | None = None, folds: int = FOLDS) -> TrainResult:
    """Self-check, then train on every training row with the loss the check chose.

    ``progress`` hears epochs of both phases, counted on: 2 × epochs in all.
    """
    from pimbs_learn.train import train

    options = options or TrainOptions()
    if not applies(run):
        return train(run, options, progress)

    def later(done: int) -> None:
        if progress is not None:
            progress(options.epochs + done)

    t0 = time.perf_counter()
    run = with_noise(run)
    check = self_check(run, options, folds, progress)
    final = run if check.keeps_physics else replace(run, loss=BASIC)
    result = train(final, options, later)
    return replace(result, self_check=check, asked_loss=run.loss,
                   seconds=time.perf_counter() - t0)
