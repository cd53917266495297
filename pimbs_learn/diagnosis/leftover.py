"""What the named effects leave unexplained: is the rest noise, and if not, where is it?

After the selected effects, each channel's residual (the torque at each joint, the length
of each muscle) is regressed on what real unmodelled physics would depend on: the pose
(each joint's angle, quadratic), the approach directions (hysteresis), the temperature and
time (creep). Noise depends on none of these. Partial F-tests per factor group,
Bonferroni-corrected over channels and groups at the diagnosis' ``P_VALUE``, say whether
structure is left and where. A structured rest is reported as such — "no effect of the
library explains it" — instead of being stretched over a wrong effect.

Two things look like structure and are not missing physics. The model's own approximations
(a polynomial body schema, a fitted gravity function) leave pose-shaped residuals: with a
reference, the same test on the clean simulation of the same poses measures them, and only
structure clearly stronger than the reference's (``REFERENCE_MARGIN`` × its F) counts.
A factor must also explain at least ``MIN_SHARE`` of
the residual variance (partial R²). Recordings diagnosed together each keep a constant of
their own (``_baseline``). Length residuals are never tested against the pose (a
routing the schema cannot follow is the schema's business). Measured tensions are not
used as regressors: their own noise is
in the torque residual, so they would always "explain" some of it.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import f as f_dist

from pimbs_learn.diagnosis.fit import fit_effects
from pimbs_learn.diagnosis.model import Fit, Physics, Samples, evaluate, sensor_units
from pimbs_learn.diagnosis.select import P_VALUE

REFERENCE_MARGIN = 2.0
# ... and only structure that carries a real share of what is left: with hundreds of rows a
# schema's approximation error is "significant" yet small; a missing effect is not.
MIN_SHARE = 0.2


def _groups(data: Samples, joints: list[str], pose: bool) -> dict[str, np.ndarray]:
    def unit(x):
        x = np.asarray(x, float)
        return (x - x.mean(0)) / np.maximum(x.std(0), 1e-12)

    groups = {}
    if pose:
        for k, name in enumerate(joints):
            x = unit(data.theta[:, k])
            groups[f"range of {name}"] = np.stack([x, x**2 - np.mean(x**2)], 1)
    a = data.approach
    groups["approach direction"] = unit(a[:, a.std(0) > 0]) if np.any(a.std(0) > 0) else None
    groups["temperature"] = unit(data.temperature.mean(1, keepdims=True))
    t = unit(data.time)
    groups["time"] = np.stack([t, t**2 - np.mean(t**2)], 1)
    return {k: v for k, v in groups.items() if v is not None and v.size}


def _f_test(y: np.ndarray, full: np.ndarray, reduced: np.ndarray
            ) -> tuple[float, float, float]:
    """(F, p, partial R²) of the columns in ``full`` beyond ``reduced`` (both include the
    constant)."""
    n = len(y)
    rss = []
    for x in (reduced, full):
        coef, *_ = np.linalg.lstsq(x, y, rcond=None)
        rss.append(float(np.sum((y - x @ coef) ** 2)))
    q = full.shape[1] - reduced.shape[1]
    dof = n - full.shape[1]
    if q <= 0 or dof <= 0 or rss[1] <= 0:
        return 0.0, 1.0, 0.0
    f = (rss[0] - rss[1]) / q / (rss[1] / dof)
    return float(f), float(f_dist.sf(f, q, dof)), float((rss[0] - rss[1]) / rss[0])


def _channels(r_len: np.ndarray, r_tau: np.ndarray, joints: list[str], muscles: list[str]):
    return ([(f"torque at {name}", r_tau[:, k], True, "N·m") for k, name in enumerate(joints)]
            + [(f"length of {name}", r_len[:, j], False, "m") for j, name in enumerate(muscles)])


def _baseline(data: Samples) -> np.ndarray:
    """Columns both models of every test hold: the constant, and one per recording after
    the first. Each session zeroes its loadcells and homes its motors at its start, so a
    residual that differs between recordings by a constant is not missing physics; with
    sessions of different loads and temperatures it would read as a dependence on them."""
    cols = [np.ones((data.n, 1))]
    if data.session is not None:
        cols += [(data.session == s)[:, None] - np.mean(data.session == s)
                 for s in np.unique(data.session)[1:]]
    return np.hstack(cols)


def _group_tests(y: np.ndarray, groups: dict[str, np.ndarray], base: np.ndarray
                 ) -> dict[str, tuple]:
    full = np.hstack([base, *groups.values()])
    return {name: _f_test(y, full, np.hstack([base, *(v for k, v in groups.items()
                                                      if k != name)]))
            for name in groups}


def leftover(physics: Physics, fit: Fit, data: Samples, joints: list[str],
             muscles: list[str], reference: Samples | None = None) -> dict:
    """JSON-ready account of the residual after the named effects."""
    r_len, r_tau = evaluate(physics, fit, data)
    channels = _channels(r_len, r_tau, joints, muscles)
    ref_channels = None
    if reference is not None and reference.n == data.n:
        ref_fit = fit_effects(physics, reference, sensor_units(reference))
        ref_channels = _channels(*evaluate(physics, ref_fit, reference), joints, muscles)
    n_groups = len(_groups(data, joints, True))
    threshold = P_VALUE / (len(channels) * n_groups)
    found = []
    base = _baseline(data)
    ref_base = None if ref_channels is None else _baseline(reference)
    for c, (label, y, pose, unit) in enumerate(channels):
        tests = _group_tests(y, _groups(data, joints, pose), base)
        ref_tests = (_group_tests(ref_channels[c][1], _groups(reference, joints, pose),
                                  ref_base)
                     if ref_channels else {})
        where = [{"factor": name, "F": f, "p_value": p, "share": share,
                  "F_reference": ref_tests[name][0] if name in ref_tests else None}
                 for name, (f, p, share) in tests.items()
                 if p < threshold and share >= MIN_SHARE
                 and (name not in ref_tests or f > REFERENCE_MARGIN * ref_tests[name][0])]
        if where:
            where.sort(key=lambda w: -w["F"])
            found.append({"channel": label, "p_value": min(w["p_value"] for w in where),
                          "residual_rms": float(np.sqrt(np.mean(y**2))), "unit": unit,
                          "depends_on": where})
    return {"consistent_with_noise": not found, "threshold_p": threshold, "structure": found,
            "tested": "each joint's torque and each muscle's length residual against pose "
                      "(torques only), approach directions, temperature and time"
                      + ("; pose structure only where stronger than in the reference"
                         if ref_channels else "")}


def leftover_text(left: dict) -> list[str]:
    if left["consistent_with_noise"]:
        return ["What is left is consistent with noise: no joint's torque or muscle's length "
                "residual depends on pose, approach, temperature or time."]
    lines = ["What is left is NOT noise, and no effect of the library explains it:"]
    for s in left["structure"]:
        factors = ", ".join(w["factor"] for w in s["depends_on"][:3]) or "several factors"
        lines.append(f"  - {s['channel']} (residual RMS {s['residual_rms']:.3g} {s['unit']}) "
                     f"depends on {factors} (p {s['p_value']:.1e})")
    return lines
