"""From a recording and the user's choices to a ready :class:`Run` (what `pimbs train` does
before any training): load, split or pair with an evaluation recording, fill τ, and refuse
combinations that cannot work, with a message saying what to do.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from pimbs_learn.data import (
    LearnError,
    Samples,
    check_compatible,
    fill_gravity,
    load_robot,
    load_samples,
    split,
)
from pimbs_learn.losses import LossConfig
from pimbs_learn.run import Run


def prepare_run(data: str | Path, loss: LossConfig, atl: bool = True,
                n_train: int | None = None, eval_path: str | Path | None = None,
                seed: int = 0, robot: str | None = None,
                note: Callable[[str], None] | None = None) -> Run:
    """Build the run `pimbs train` asked for.

    With --eval the model is evaluated on that recording (trained on all of DATA, or on
    n_train rows of it); without, n_train rows are drawn (seeded) and the rest evaluates.
    A ``robot`` is always checked against DATA; ``note`` hears when it is not needed.
    """
    samples = load_samples(data)
    if robot is not None:
        load_robot(robot, samples)
        if note is not None and not (loss.pinn and not np.isfinite(samples.tau).all()):
            why = ("DATA has tau_gravity in every row" if loss.pinn
                   else f"the {loss.name} loss needs no gravity torque")
            note(f"--robot {robot} matches {samples.path} but is not used: {why}")
    if eval_path is not None:
        ev = load_samples(eval_path)
        check_compatible(samples, ev)
        if n_train is None:
            tr = samples
        elif n_train > samples.n_samples or n_train < 1:
            raise LearnError(f"--n-train {n_train} is outside 1..{samples.n_samples}, the "
                             f"rows of {samples.path}")
        else:
            tr = samples.take(np.sort(np.random.default_rng(seed).permutation(
                samples.n_samples)[:n_train]))
    else:
        if n_train is None:
            raise LearnError("give --n-train N (train on N rows, evaluate on the rest) or "
                             "--eval FILE (a separate evaluation recording)")
        tr, ev = split(samples, n_train, seed)
    _check_tension(tr, atl, loss)
    if loss.pinn:
        tr = fill_gravity(tr, robot)
    run = Run(tr, ev, loss, seed=seed, atl=atl)
    run.check()
    return run


def _check_tension(tr: Samples, atl: bool, loss: LossConfig) -> None:
    """An ATL-Map or a PINN loss is meaningless without measured tension."""
    if not (atl or loss.pinn):
        return  # an AL-Map with Basic/Const needs only θ and l
    if not np.abs(tr.tension).max() > 0:
        need = "the ATL-Map (θ, f) → l" if atl else "the PINN loss (Gᵀf + τ)"
        raise LearnError(f"{tr.path}: the tension column is zero in every training row, but "
                         f"{need} needs measured tension; use --map al and a loss without "
                         "'pinn'")
