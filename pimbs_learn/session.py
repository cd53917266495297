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
from pimbs_learn.default_split import default_n_train, split_note
from pimbs_learn.graph import MLP
from pimbs_learn.losses import REPORT_SCALE, LossConfig
from pimbs_learn.prior import PriorUnavailable, load_prior
from pimbs_learn.run import Run


def prepare_run(data: str | Path, loss: LossConfig, atl: bool = True,
                n_train: int | None = None, eval_path: str | Path | None = None,
                seed: int = 0, robot: str | None = None, structure: str = MLP,
                prior: bool = False, note: Callable[[str], None] | None = None) -> Run:
    """Build the run `pimbs train` asked for.

    With --eval the model is evaluated on that recording (trained on all of DATA, or on
    n_train rows of it); without, n_train rows are drawn (seeded) and the rest evaluates;
    without either, 80 % of the rows are drawn (seeded) and ``note`` hears which evaluate.
    A ``robot`` is always checked against DATA; ``note`` hears when it is not needed.
    With ``prior`` the robot description (``robot``, else the recording's robot) is the
    prior when it loads and matches; otherwise training goes on without one and ``note``
    hears why.
    """
    samples = load_samples(data)
    if robot is not None:
        load_robot(robot, samples)
        used = (prior and atl) or (loss.pinn and not np.isfinite(samples.tau).all())
        if note is not None and not used:
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
            n_train = default_n_train(samples.n_samples, samples.path)
            if note is not None:
                note(split_note(samples.n_samples, n_train, seed))
        tr, ev = split(samples, n_train, seed)
    _check_tension(tr, atl, loss)
    if loss.pinn:
        tr = fill_gravity(tr, robot)
    arrays, name = None, None
    if prior and atl:
        name = robot or tr.robot
        try:
            if not name:
                raise PriorUnavailable("the recording names no robot (give --robot)")
            arrays = load_prior(name, tr.joints, tr.muscles)
        except PriorUnavailable as e:
            name = None
            if note is not None:
                note(f"no geometric prior: {e}")
    run = Run(tr, ev, loss, seed=seed, atl=atl, structure=structure if atl else MLP,
              prior=arrays, prior_robot=name)
    run.check()
    return run


def model_error(run: Run) -> dict[str, float] | None:
    """The prior's own error on the evaluation samples (l_model = h_geom − log1p(f)/K):
    L_eval ×1e5 and rms in mm, or None without a prior."""
    if run.prior is None:
        return None
    import torch

    from pimbs_learn.prior import GeometricPrior

    ev = run.eval
    with torch.no_grad():
        h, _ = GeometricPrior.from_numpy(run.prior)(torch.from_numpy(ev.theta),
                                                    torch.from_numpy(ev.tension))
    mse = float(((h.numpy() - ev.length) ** 2).mean())
    return {"eval_loss": mse * REPORT_SCALE, "rms_mm": 1e3 * mse ** 0.5}


def _check_tension(tr: Samples, atl: bool, loss: LossConfig) -> None:
    """An ATL-Map or a PINN loss is meaningless without measured tension."""
    if not (atl or loss.pinn):
        return  # an AL-Map with Basic/Const needs only θ and l
    if not np.abs(tr.tension).max() > 0:
        need = "the ATL-Map (θ, f) → l" if atl else "the PINN loss (Gᵀf + τ)"
        raise LearnError(f"{tr.path}: the tension column is zero in every training row, but "
                         f"{need} needs measured tension; use --map al and a loss without "
                         "'pinn'")
