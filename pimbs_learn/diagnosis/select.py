"""Choosing the missing physics: screen each effect's units, then compare effects.

For each effect, units (muscles, joints, subtrees) are added greedily while the drop in
whitened residual, from a linearisation at the current fit, beats a strict χ² threshold.
The effect is then refitted exactly and scored three ways, all of which must agree before
it is named:

* a likelihood-ratio test against the current model (p below ``P_VALUE``);
* ΔBIC > 0, which also ranks effects — with a reference recording, the ΔBIC of the
  real parameters against the reference's own fit of the same model (what the real data
  want beyond the nuisance models' approximation, see ``anchor``), never above the plain
  ΔBIC;
* five-fold cross-validation: held-out residuals must shrink, by ``MIN_CV_GAIN`` overall
  and significantly sample by sample (paired z ≥ ``MIN_CV_Z``), so structure that a
  flexible effect could absorb on the training rows is not reported, while an effect on a
  few muscles of many still is.

Effects are added one at a time (forward selection), the strongest first, each on top of
a joint refit of all those already selected (the screen's linearisation lets them move
too); after each addition, earlier effects that the
new one makes redundant are dropped again (backward check).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2

from pimbs_learn.diagnosis.fit import _whiten, cross_validate, fit_effects, log_lik_at
from pimbs_learn.diagnosis.model import (
    EFFECTS,
    SPRING,
    Fit,
    Physics,
    Samples,
    Unit,
    _moves_pose,
    apply_effects,
    fit_schema,
    residuals,
    units_of,
)

P_VALUE = 1e-6      # per test; strict, since recordings have hundreds of rows
MIN_CV_GAIN = 0.01  # held-out score must improve by at least 1 % ...
MIN_CV_Z = 5.0      # ... and significantly: paired z of per-sample held-out residuals
UNIT_Z = float(np.sqrt(chi2.isf(P_VALUE, 1)))  # a muscle/joint's own parameter: |p/se|
# A link's mass: one subtree. Subtrees' potentials overlap, so two would trade off
# against each other with meaningless, cancelling scales.
MAX_GROUPS = {"link_mass": 1}
FD_STEP = {"tension_offset": 1e-2, "tension_gain": 1e-4, "thermal_drift": 1e-3,
           "tendon_friction": 1e-4, "elastic_stiffness": 1e-4, "joint_offset": 1e-6,
           "link_mass": 1e-4, "sensor_lag": 1e-4, "loadcell_hysteresis": 1e-2,
           SPRING: 1e-3}


@dataclass
class Candidate:
    effect: str
    units: list[Unit]
    fit: Fit
    lr: float
    df: int
    p_value: float
    delta_bic: float
    cv_before: dict
    cv_after: dict | None
    rank_bic: float = float("nan")  # ΔBIC that ranks candidates (anchored at the reference)
    ref_fit: Fit | None = None      # the reference's own fit of ``units``

    @property
    def cv_gain(self) -> float:
        if self.cv_after is None:
            return float("nan")
        return 1.0 - self.cv_after["score"] / self.cv_before["score"]

    @property
    def cv_z(self) -> float:
        """Paired z statistic of the held-out improvement, sample by sample."""
        if self.cv_after is None:
            return float("nan")
        d = self.cv_before["per_sample"] - self.cv_after["per_sample"]
        return float(d.mean() / max(d.std(ddof=1) / np.sqrt(len(d)), 1e-300))

    @property
    def significant(self) -> bool:
        return (self.cv_after is not None and self.p_value < P_VALUE and self.delta_bic > 0
                and self.cv_gain >= MIN_CV_GAIN and self.cv_z >= MIN_CV_Z)


def _whitened(physics: Physics, data: Samples, units: list[Unit], params: np.ndarray,
              sigma) -> np.ndarray:
    state = apply_effects(physics, data, units, params)
    key = None if _moves_pose(units) else "full"  # same poses as the full fit: share its cache
    weights = fit_schema(physics, state, data, key)
    return _whiten(*residuals(physics, state, data, weights, key), *sigma)


def fd_column(physics: Physics, data: Samples, fit: Fit, unit: Unit, r0: np.ndarray,
              sigma) -> np.ndarray:
    """∂(whitened residual)/∂(parameter of ``unit``) at ``fit`` (schema refitted), by a
    finite step: moving the unit's fitted value, or adding the unit to the fit."""
    step = FD_STEP[unit.effect]
    if unit in fit.units:
        params = fit.params.copy()
        params[fit.units.index(unit)] += step
        plus = _whitened(physics, data, fit.units, params, sigma)
    else:
        plus = _whitened(physics, data, [*fit.units, unit], np.append(fit.params, step), sigma)
    return (plus - r0) / step


def _base_columns(physics: Physics, data: Samples, base: Fit, r0: np.ndarray,
                  sigma) -> np.ndarray:
    """Orthonormal basis of ∂(whitened residual)/∂(each parameter of ``base``)."""
    if not base.units:
        return np.zeros((len(r0), 0))
    cols = [fd_column(physics, data, base, u, r0, sigma) for u in base.units]
    q, r = np.linalg.qr(np.stack(cols, axis=1))
    keep = np.abs(np.diag(r)) > 1e-9 * max(np.abs(np.diag(r)).max(), 1e-300)
    return q[:, keep]


SEEN_SHARE = 0.01  # of a joint's torque noise: what a doubled mass must move to be seen


def mass_seen(physics: Physics, data: Samples, unit: Unit, sigma_tau: np.ndarray) -> bool:
    """Whether doubling the mass behind ``unit`` (β = 1) moves some joint's torque, RMS over
    the recording's poses, by at least ``SEEN_SHARE`` of that joint's noise.

    A link turning about a vertical axis, or one whose centre of mass lies on its joint's
    axis, adds nothing to that joint's gravity potential: the fitted gravity function keeps
    only numerical dust there (10⁻⁷ N·m on a drawn arm). Its scale is then free to grow to
    10⁴ and fit whatever small structure the residual holds, so a rival or a name would
    rest on that dust instead of on a mass."""
    moved = apply_effects(physics, data, [unit], np.ones(1)).tau - data.tau
    return bool(np.any(np.sqrt(np.mean(moved**2, axis=0)) >= SEEN_SHARE * sigma_tau))


def screen(physics: Physics, data: Samples, base: Fit, effect: str) -> list[Unit]:
    """Units of ``effect`` that the residuals of ``base`` ask for (greedy, linearised)."""
    sigma = (base.sigma_len, base.sigma_tau)
    every = units_of(effect, physics, data)
    # an effect may grow, never repeat
    groups = [g for g in every if not any(u in base.units for u in g)]
    if effect == "link_mass":
        groups = [g for g in ([u for u in g if mass_seen(physics, data, u, base.sigma_tau)]
                              for g in groups) if g]
    taken = sum(any(u in base.units for u in g) for g in every)
    if not groups or taken >= MAX_GROUPS.get(effect, len(groups) + taken):
        return []
    r0 = _whitened(physics, data, base.units, base.params, sigma)
    # the effects already selected are refitted jointly with the new one, so their columns
    # are projected out: a drift on the muscle whose offset is already named is mostly that
    # offset (T − T_zero has a large mean), and only what the offset cannot take is news
    held = _base_columns(physics, data, base, r0, sigma)
    cols = {}
    for group in groups:
        for u in group:
            col = fd_column(physics, data, base, u, r0, sigma)
            cols[u] = col - held @ (held.T @ col)
    chosen: list[list[Unit]] = []
    rss = float(r0 @ r0)
    while len(chosen) < min(len(groups), MAX_GROUPS.get(effect, len(groups))):
        best, best_rss = None, rss
        for group in groups:
            if group in chosen:
                continue
            trial = [u for g in chosen for u in g] + group
            a = np.stack([cols[u] for u in trial], axis=1)
            coef, *_ = np.linalg.lstsq(a, -r0, rcond=None)
            new_rss = float(np.sum((r0 + a @ coef) ** 2))
            if new_rss < best_rss:
                best, best_rss = group, new_rss
        if best is None or rss - best_rss < chi2.isf(P_VALUE, len(best)):
            break
        chosen.append(best)
        rss = best_rss
    return [u for g in chosen for u in g]


def fit_candidate(physics: Physics, data: Samples, base: Fit, effect: str,
                  cv_base: dict) -> Candidate | None:
    """Screen and refit one effect on top of ``base`` (no cross-validation yet)."""
    units = screen(physics, data, base, effect)
    if not units:
        return None
    all_units = [*base.units, *units]
    fit = fit_effects(physics, data, all_units, x0=np.append(base.params, np.zeros(len(units))),
                      key="full")
    if effect != "link_mass" and fit.cov is not None and len(units) > 1:
        # the screen is linear and greedy: a muscle it took along that the exact joint fit
        # finds indistinguishable from zero is not part of the effect
        z = np.abs(fit.params) / np.sqrt(np.maximum(np.diag(fit.cov), 1e-300))
        weak = [u for u in units if z[all_units.index(u)] < UNIT_Z]
        if weak and len(weak) < len(units):
            units = [u for u in units if u not in weak]
            fit = _refit(physics, data, base, units, fit)
    return _candidate(effect, units, fit, base, data.n, cv_base)


def _refit(physics: Physics, data: Samples, base: Fit, units: list[Unit], start: Fit) -> Fit:
    """Joint fit of ``base``'s units and ``units``, started at ``start``'s estimates."""
    all_units = [*base.units, *units]
    return fit_effects(physics, data, all_units, key="full",
                       x0=np.array([start.params[start.units.index(u)] for u in all_units]))


def _candidate(effect: str, units: list[Unit], fit: Fit, base: Fit, n: int,
               cv_before: dict) -> Candidate:
    """The candidate ``fit`` makes against ``base``: LR test and ΔBIC, not yet CV'd."""
    df = len(units)
    lr = max(2.0 * (fit.log_lik - base.log_lik), 0.0)
    return Candidate(effect, units, fit, lr, df, float(chi2.sf(lr, df)), lr - df * np.log(n),
                     cv_before, None)


def _cross_validate(physics: Physics, data: Samples, cand: Candidate, base: Fit) -> None:
    cand.cv_after = cross_validate(physics, data, cand.fit.units,
                                   (base.sigma_len, base.sigma_tau), x0=cand.fit.params)


def _drop(fit: Fit, units: list[Unit]) -> tuple[list[Unit], np.ndarray]:
    keep = [i for i, u in enumerate(fit.units) if u not in units]
    return [fit.units[i] for i in keep], fit.params[keep]


def prune(physics: Physics, data: Samples, named: list[Candidate], current: Fit,
          newest: str) -> tuple[list[Candidate], Fit]:
    """Backward step: drop a named effect the others now explain (weakest first).

    An effect named early may have stood in for two that were present together (an offset
    and a stiffness for one gain error); once the right effects are in the model, its own
    likelihood-ratio test must still pass, or it goes.
    """
    while len(named) > 1:
        worst, worst_fit, worst_lr = None, None, np.inf
        for cand in (c for c in named if c.effect != newest):
            units, params = _drop(current, cand.units)
            reduced = fit_effects(physics, data, units, x0=params, key="full")
            lr = max(2.0 * (current.log_lik - reduced.log_lik), 0.0)
            if lr < worst_lr:
                worst, worst_fit, worst_lr = cand, reduced, lr
        df = len(worst.units)
        if chi2.sf(worst_lr, df) < P_VALUE and worst_lr - df * np.log(data.n) > 0:
            break
        named = [c for c in named if c is not worst]
        current = worst_fit
    return _prune_units(physics, data, named, current)


def _prune_units(physics: Physics, data: Samples, named: list[Candidate], current: Fit
                 ) -> tuple[list[Candidate], Fit]:
    """Drop muscles/joints of a named effect that the joint fit finds indistinguishable
    from zero (a gain taken along on a muscle whose offset came later)."""
    if current.cov is None:
        return named, current
    z = np.abs(current.params) / np.sqrt(np.maximum(np.diag(current.cov), 1e-300))
    weak = []
    for c in named:
        low = [u for u in c.units if z[current.units.index(u)] < UNIT_Z]
        if c.effect != "link_mass" and len(low) < len(c.units):
            weak += low
    if not weak:
        return named, current
    named = [replace(c, units=[u for u in c.units if u not in weak]) for c in named]
    units, params = _drop(current, weak)
    return named, fit_effects(physics, data, units, x0=params, key="full")


MAX_EFFECTS = 5
CV_PER_ROUND = 3  # cross-validate at most this many of a round's best candidates


def _cv_of(physics: Physics, data: Samples, fit: Fit) -> dict:
    """Held-out score of ``fit``'s model on the scale of its own noise levels."""
    return cross_validate(physics, data, fit.units, (fit.sigma_len, fit.sigma_tau),
                          x0=fit.params)


def reference_explains(cand: Candidate, ref_base: Fit) -> bool:
    """Is the candidate the model's own approximation rather than missing physics?

    The reference is a clean simulation of the same poses. Where the nuisance models (a
    polynomial body schema, a fitted gravity function) cannot follow the arm exactly, the
    reference "wants" the same effect as the real data. Then the effect counts only if the
    real parameters differ significantly from the reference's. Both sides fit the same
    model — the effects already named plus the candidate (``anchor``) — so a gain the
    reference wants only beside a link mass is compared with the real gain beside it.
    """
    fit = cand.ref_fit
    df = len(cand.units)
    if chi2.sf(max(2.0 * (fit.log_lik - ref_base.log_lik), 0.0), df) >= P_VALUE:
        return False
    idx = [cand.fit.units.index(u) for u in cand.units]
    if cand.fit.cov is None or fit.cov is None:
        return False
    diff = cand.fit.params[idx] - fit.params[idx]
    cov = cand.fit.cov[np.ix_(idx, idx)] + fit.cov[np.ix_(idx, idx)]
    stat = float(diff @ np.linalg.pinv(cov) @ diff)
    return chi2.sf(stat, df) >= P_VALUE


def anchor(physics: Physics, data: Samples, reference: Samples, cand: Candidate,
           ref_base: Fit) -> None:
    """Rank ``cand`` by what the real data want beyond what the reference wants.

    A clean simulation of the same poses already "wants" some of every effect where the
    nuisance models (polynomial schema, fitted gravity function) do not follow the arm;
    two effects that soak up that approximation differently (a gain on the muscles that
    carry a link, and that link's mass) are then ranked by how well they fit the
    approximation error rather than the concealed physics. So the likelihood ratio that
    ranks is taken against the candidate's units held at the reference's own estimates
    instead of at zero (the likelihood counterpart of ``reference_explains``' Wald test).
    The reference fits the same model as the real data (``ref_base``: the effects already
    named, fitted on the reference), since what it wants of one effect depends on the
    others beside it.
    """
    cand.ref_fit = fit_effects(physics, reference, cand.fit.units, key="ref",
                               x0=np.append(ref_base.params, np.zeros(len(cand.units))))
    params = cand.fit.params.copy()
    for u in cand.units:
        i = cand.fit.units.index(u)
        params[i] = cand.ref_fit.params[i]
    at_ref = log_lik_at(physics, data, cand.fit.units, params, key="full")
    # a discount, never a bonus: where the reference's wants do not carry over to the real
    # arm (another routing, another approximation error) its estimates can fit the real
    # data worse than no effect at all, and that must not lift a candidate above its own
    # evidence against zero
    cand.rank_bic = min(2.0 * (cand.fit.log_lik - at_ref) - cand.df * np.log(data.n),
                        cand.delta_bic)


def reference_units(cand: Candidate) -> list[Unit]:
    """Muscles/joints of a candidate that the reference wants just as much.

    ``reference_explains`` judges a candidate as a whole; a joint offset found on two
    joints may be real on one and, on the other, the same approximation the clean
    reference wants (5-DOF, mass + shoulder-roll offset, another routing: forearm yaw
    0.14 ± 0.03 rad on the real arm, 0.22 ± 0.03 on the reference). Such units go, unit by
    unit, with the same test: the reference's own parameter significant, the real one not
    different from it. A link mass' units are one subtree and are not split.
    """
    ref = cand.ref_fit
    if (ref is None or cand.effect == "link_mass" or len(cand.units) < 2
            or cand.fit.cov is None or ref.cov is None):
        return []
    out = []
    for u in cand.units:
        i = cand.fit.units.index(u)
        se_ref, se = np.sqrt(max(ref.cov[i, i], 1e-300)), np.sqrt(max(cand.fit.cov[i, i], 0.0))
        wanted = abs(ref.params[i]) >= UNIT_Z * se_ref
        same = abs(cand.fit.params[i] - ref.params[i]) < UNIT_Z * np.hypot(se, se_ref)
        if wanted and same:
            out.append(u)
    return out if len(out) < len(cand.units) else []  # all of them: the whole-candidate veto


def _without(physics: Physics, data: Samples, reference: Samples, cand: Candidate,
             base: Fit, ref_base: Fit, drop: list[Unit]) -> Candidate:
    """``cand`` refitted without the units in ``drop`` (anchored again, not yet CV'd)."""
    units = [u for u in cand.units if u not in drop]
    fit = _refit(physics, data, base, units, cand.fit)
    out = _candidate(cand.effect, units, fit, base, data.n, cand.cv_before)
    anchor(physics, data, reference, out, ref_base)
    return out


def _merge(named: list[Candidate], best: Candidate) -> list[Candidate]:
    """Add ``best``; more units of an effect already named join that effect."""
    old = next((c for c in named if c.effect == best.effect), None)
    if old is None:
        return [*named, best]
    grown = replace(old, units=[*old.units, *best.units], fit=best.fit)
    return [grown if c is old else c for c in named]


MAX_ROUNDS = 6


def select_effects(physics: Physics, data: Samples, null: Fit,
                   effects: tuple[str, ...] = EFFECTS, progress=None,
                   reference: Samples | None = None
                   ) -> tuple[list[Candidate], list[Candidate], dict, Fit]:
    """Forward selection with a backward check after each step.

    Each round tests every remaining effect on top of the model with all selected effects
    (jointly refitted), names the strongest that passes, then drops any earlier effect the
    new one made redundant. Every round scores held-out residuals on the noise scale of
    the current model, so a weak second effect beside a strong first one is judged on the
    residuals that are left, not on the scale of the raw mismatch.

    Returns (named effects, every candidate tried, null CV score, joint fit of the named).
    """
    cv_null = cross_validate(physics, data, null.units, (null.sigma_len, null.sigma_tau),
                             x0=null.params)
    base, cv_base = null, cv_null
    named: list[Candidate] = []
    tried: list[Candidate] = []
    if reference is not None and reference.n != data.n:
        reference = None
    for _ in range(MAX_ROUNDS):
        round_candidates = []
        for effect in effects:
            if progress:
                progress(effect)
            cand = fit_candidate(physics, data, base, effect, cv_base)
            if cand is not None:
                round_candidates.append(cand)
        tried += round_candidates
        ranked = [c for c in round_candidates if c.p_value < P_VALUE and c.delta_bic > 0]
        ref_base = (fit_effects(physics, reference, base.units, x0=base.params, key="ref")
                    if reference is not None and ranked else None)
        for cand in ranked:
            if ref_base is None:
                cand.rank_bic = cand.delta_bic
            else:
                anchor(physics, data, reference, cand, ref_base)
        ranked.sort(key=lambda c: -c.rank_bic)
        best = None
        for cand in ranked[:CV_PER_ROUND]:
            drop = reference_units(cand) if ref_base is not None else []
            if drop:
                cand = _without(physics, data, reference, cand, base, ref_base, drop)
                tried.append(cand)
            _cross_validate(physics, data, cand, base)
            if cand.significant and not (ref_base is not None and reference_explains(
                    cand, ref_base)):
                best = cand
                break
        if best is None:
            break
        named, base = prune(physics, data, _merge(named, best), best.fit, best.effect)
        if len({c.effect for c in named}) > MAX_EFFECTS:
            break
        cv_base = _cv_of(physics, data, base)
    return named, tried, cv_null, base
