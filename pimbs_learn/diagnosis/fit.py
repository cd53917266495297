"""Fitting effect parameters by maximum likelihood, and scoring fits on held-out samples.

For given effect parameters the body schema is a linear least-squares problem, so it is
profiled out (variable projection); the few effect parameters are found by
Gauss–Newton (``scipy.optimize.least_squares``) on the residuals of both channels, each
whitened by its own noise level, which is re-estimated once from the fit.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from pimbs_learn.diagnosis.model import (
    Fit,
    Physics,
    Samples,
    State,
    Unit,
    _moves_pose,
    apply_effects,
    evaluate,
    fit_schema,
    profile_log_lik,
    residuals,
    sensor_units,
)

SIGMA_FLOOR = (1e-7, 1e-5)  # m, N·m: never trust a channel more than its sensors allow
# whitened residual of every row at a trial point whose corrections are not finite numbers
DIVERGED = 1e8


def _whiten(r_len, r_tau, sigma_len, sigma_tau) -> np.ndarray:
    return np.concatenate([(r_len / sigma_len).ravel(), (r_tau / sigma_tau).ravel()])


def _sigmas(r_len: np.ndarray, r_tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return (np.maximum(np.sqrt(np.mean(r_len**2, 0)), SIGMA_FLOOR[0]),
            np.maximum(np.sqrt(np.mean(r_tau**2, 0)), SIGMA_FLOOR[1]))


def _finite(state: State) -> bool:
    parts = (state.theta, state.tension, state.kappa, state.tau, state.scale, state.length)
    return bool(np.isfinite(state.len_scale)) and all(
        part is None or bool(np.isfinite(part).all()) for part in parts)


def fit_effects(physics: Physics, data: Samples, units: list[Unit],
                x0: np.ndarray | None = None, sigma: tuple | None = None,
                key=None, passes: int = 2) -> Fit:
    """Maximum-likelihood parameters of ``units`` on ``data`` (schema profiled out).

    A trial point whose corrections overflow (a capstan exponent or a gain driven far past
    anything physical while several effects trade off against each other) scores
    ``DIVERGED`` on every residual, so the search steps back from it: an explanation that
    only fits by running away loses to the others instead of ending the diagnosis."""
    cache_key = None if _moves_pose(units) else key

    def resid_at(params: np.ndarray):
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            state = apply_effects(physics, data, units, params)
            if not _finite(state):
                return None, None
            weights = fit_schema(physics, state, data, cache_key)
            r = residuals(physics, state, data, weights, cache_key)
        if not all(np.isfinite(part).all() for part in r):
            return None, None
        return r, weights

    def whitened(params: np.ndarray, s_len: np.ndarray, s_tau: np.ndarray) -> np.ndarray:
        r, _ = resid_at(params)
        return np.full(size, DIVERGED) if r is None else _whiten(*r, s_len, s_tau)

    def accepted(params: np.ndarray):  # the start, or a point the search kept: finite
        r, weights = resid_at(params)
        if r is None:
            raise FloatingPointError(f"effect parameters {params} of {units} give corrections "
                                     "that are not finite numbers")
        return r, weights

    params = np.zeros(len(units)) if x0 is None else np.asarray(x0, float)
    (r_len, r_tau), weights = accepted(params)
    size = r_len.size + r_tau.size
    s_len, s_tau = sigma if sigma is not None else _sigmas(r_len, r_tau)
    cov = None
    if units:
        for _ in range(passes):  # fit, re-estimate the noise levels, fit again
            sol = least_squares(whitened, params, args=(s_len, s_tau), method="lm",
                                x_scale="jac", max_nfev=200 * len(units))
            params = sol.x
            (r_len, r_tau), weights = accepted(params)
            s_len, s_tau = _sigmas(r_len, r_tau)
        jac = sol.jac
        dof = max(len(sol.fun) - len(params), 1)
        scale = float(np.sum(_whiten(r_len, r_tau, s_len, s_tau) ** 2) / dof)
        try:
            cov = np.linalg.pinv(jac.T @ jac) * scale
        except np.linalg.LinAlgError:
            cov = None
    return Fit(units, params, weights, s_len, s_tau, profile_log_lik(r_len, r_tau), cov)


def log_lik_at(physics: Physics, data: Samples, units: list[Unit], params: np.ndarray,
               key=None) -> float:
    """Profile log-likelihood of ``data`` with the effect parameters held at ``params``."""
    cache_key = None if _moves_pose(units) else key
    state = apply_effects(physics, data, units, np.asarray(params, float))
    weights = fit_schema(physics, state, data, cache_key)
    return profile_log_lik(*residuals(physics, state, data, weights, cache_key))


def folds(n: int, k: int, seed: int = 0) -> list[np.ndarray]:
    """Held-out index sets: a seeded shuffle cut into ``k`` parts."""
    perm = np.random.default_rng(seed).permutation(n)
    return [np.sort(part) for part in np.array_split(perm, k)]


def cross_validate(physics: Physics, data: Samples, units: list[Unit],
                   sigma: tuple[np.ndarray, np.ndarray], k: int = 5,
                   x0: np.ndarray | None = None) -> dict:
    """Held-out residuals of a model refitted without each fold.

    Returns the mean whitened squared residual (``score``, with the fixed ``sigma`` so
    that models compare on one scale) and the physical RMS of each channel.
    """
    s_len, s_tau = sigma
    sq, lens, taus, order = [], [], [], []
    for i, test in enumerate(folds(data.n, k)):
        train_idx = np.setdiff1d(np.arange(data.n), test)
        train = data.rows(train_idx)
        fit = fit_effects(physics, train, units, x0=x0, sigma=sigma, key=("cv", i), passes=1)
        r_len, r_tau = evaluate(physics, fit, data.rows(test))
        per_sample = np.hstack([r_len / s_len, r_tau / s_tau]) ** 2
        sq.append(per_sample.sum(axis=1))
        order.append(test)
        lens.append(r_len)
        taus.append(r_tau)
    r_len, r_tau = np.concatenate(lens), np.concatenate(taus)
    per_sample = np.empty(data.n)
    per_sample[np.concatenate(order)] = np.concatenate(sq)
    channels = r_len.shape[1] + r_tau.shape[1]
    return {"score": float(per_sample.mean() / channels),
            "per_sample": per_sample,
            "length_rms": float(np.sqrt(np.mean(r_len**2))),
            "torque_rms": float(np.sqrt(np.mean(r_tau**2)))}


def choose_schema(make_physics, data: Samples, options: list):
    """The body schema (``make_physics(option)``: a polynomial degree, with or without the
    robot file's routing) by the held-out likelihood of the null model: the first option
    (``options`` come simplest first) within one standard error of the best.

    A richer schema must predict held-out rows clearly better, not by chance: at a narrow
    session's floors the lengths carry the loadcells' noise and hysteresis times
    ``1/(K(1 + f))``, hundreds of micrometres, and a correction to the file's routing
    fitted to them won its folds by a few log-likelihood units while it left the moment
    arms 2–70 % off the file's, which the torque balance then read as physics
    (docs/diagnosis-notebook.md). The standard error is that of the per-fold difference
    from the best option."""
    parts = folds(data.n, 4, seed=1)
    ll = np.zeros((len(options), len(parts)))
    for k, option in enumerate(options):
        physics = make_physics(option)
        for i, test in enumerate(parts):
            train = data.rows(np.setdiff1d(np.arange(data.n), test))
            fit = fit_effects(physics, train, sensor_units(train), key=("schema", k, i))
            ll[k, i] = profile_log_lik(*evaluate(physics, fit, data.rows(test)))
    gap = ll[np.argmax(ll.sum(axis=1))] - ll  # (options, folds), ≥ 0 in sum
    se = np.sqrt(len(parts)) * gap.std(axis=1, ddof=1)
    return options[int(np.flatnonzero(gap.sum(axis=1) <= se)[0])]
