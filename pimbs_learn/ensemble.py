"""A body schema from a few samples as the mean of two networks, stored as one network.

Why: from 5–10 samples nothing in the rows tells whether each physics term pays. On
populations of drawn arms (docs/learning-notebook.md §19, §22) the physics run won on most
cells and lost on some by up to 4×, and neither the Gaussian process's check nor a K-fold
check with the networks themselves told which. The losses came mostly from L_const, the
home pose at zero tension: where a loadcell's zero has moved, or five poses extrapolate
badly to the home pose, it bends the network. So with that few samples the schema is the
mean of the network the loss asks for and the same loss without L_const, from other
initial weights: both keep the torque balance's gain, and where the home pose goes wrong
the mean loses half as much. With at most 7 samples the torque balance itself can mislead
(§22: two halves of arms disagreed there), so the other network is Basic and the mean
keeps half of the physics. Basic itself is then the mean of two Basic networks, so the two
stay the same size and the physics remains the only difference.

Two MLPs of width H averaged are exactly one MLP of width k·H: their first layers stacked,
their second layers on a block diagonal, their output layers side by side divided by k (the
series-elastic coefficients and output biases averaged). So the result is an ordinary
trained model: saved, loaded, exported and differentiated as any other.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pimbs_learn.losses import BASIC, HOME_POSE_UP_TO, LossConfig
from pimbs_learn.run import Run, TrainResult

# Runs of at most this many training samples train two networks: where the default keeps
# L_const, whose hedge the second network is (the regimes of 5 and 10 samples; §22, §24).
MEMBERS_UP_TO = HOME_POSE_UP_TO
# Up to this many training samples (the 5-sample regime of the self-check's nearest-size
# rule) the other network is Basic, not the physics without L_const (§19, §22, §24).
BASIC_PARTNER_UP_TO = 7
MEMBERS = 2
SEED_STEP = 1000  # member i starts from the initial weights of seed + i·SEED_STEP


def members_for(n_train: int) -> int:
    """How many networks a run of ``n_train`` training samples averages."""
    return MEMBERS if n_train <= MEMBERS_UP_TO else 1


def partner_loss(run: Run) -> LossConfig:
    """The loss of the networks averaged with ``run``'s.

    Beside a run with the torque balance and more than :data:`BASIC_PARTNER_UP_TO` samples
    they keep the balance and leave out the home pose: nothing in the rows tells whether
    the home pose holds (§22), so the mean keeps half of it. With at most that many, or beside
    a run without the torque balance, they are Basic (Basic then stays the same size).
    """
    if run.loss.pinn and run.train.n_samples > BASIC_PARTNER_UP_TO:
        return replace(run.loss, const=False)
    return BASIC


def member_runs(run: Run, k: int) -> list[Run]:
    """The run itself, and k − 1 runs of :func:`partner_loss` on the same rows from other
    initial weights."""
    partner = partner_loss(run)
    return [run] + [replace(run, seed=run.seed + i * SEED_STEP, loss=partner)
                    for i in range(1, k)]


def merge_params(params: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """One network's weights that compute the mean of the given networks' lengths.

    Weights as trained (w (out, in), biases (1, out)); keys outside the network (a
    geometric prior's tensors) are the same in every member and kept from the first.
    """
    k = len(params)
    if k == 1:
        return dict(params[0])
    out = dict(params[0])
    out["w1"] = np.concatenate([p["w1"] for p in params], axis=0)
    out["b1"] = np.concatenate([p["b1"] for p in params], axis=1)
    h = [p["w2"].shape[0] for p in params]
    w2 = np.zeros((sum(h), sum(h)), dtype=params[0]["w2"].dtype)
    at = np.cumsum([0] + h)
    for i, p in enumerate(params):
        w2[at[i]:at[i + 1], at[i]:at[i + 1]] = p["w2"]
    out["w2"] = w2
    out["b2"] = np.concatenate([p["b2"] for p in params], axis=1)
    out["w3"] = np.concatenate([p["w3"] for p in params], axis=1) / np.float32(k)
    out["b3"] = np.mean([p["b3"] for p in params], axis=0).astype(params[0]["b3"].dtype)
    if "c" in out:
        out["c"] = np.mean([p["c"] for p in params], axis=0).astype(params[0]["c"].dtype)
    return out


def _mean_terms(terms: list[dict[str, list[float]] | None]) -> dict[str, list[float]] | None:
    """The sensor terms of the members that fitted them (a Basic member fits none)."""
    fitted = [t for t in terms if t is not None]
    if not fitted:
        return None
    return {key: np.mean([t[key] for t in fitted], axis=0).tolist() for key in fitted[0]}


def merge(results: list[TrainResult]) -> TrainResult:
    """The mean of ``results`` (one run's members, same rows) as one TrainResult.

    Its losses are the merged network's own (training L_basic and L_eval recomputed);
    each member's seed, best epoch and L_eval are kept in ``members`` for the metrics.
    """
    from pimbs_learn.io import schema_from_result

    first = results[0]
    if len(results) == 1:
        return first
    merged = replace(first, params=merge_params([r.params for r in results]),
                     sensor_terms=_mean_terms([r.sensor_terms for r in results]),
                     seconds=max(r.seconds for r in results),
                     curve_epochs=np.zeros(0, int), curve_eval=np.zeros(0),
                     curve_train=np.zeros(0),
                     members=[{"seed": r.run.seed, "loss": r.run.loss.name,
                               "best_epoch": r.best_epoch, "eval_loss": r.eval_loss}
                              for r in results])
    schema = schema_from_result(merged)

    def mse(samples) -> float:
        pred = schema.length(samples.theta, samples.tension)
        return float(np.mean((pred - samples.length) ** 2))

    return replace(merged, train_loss=mse(first.run.train), eval_loss=mse(first.run.eval))
