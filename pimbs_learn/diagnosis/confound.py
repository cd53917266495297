"""Does this recording tell the named effect from its confounders?

Forward selection names the candidate that fits best; a recording may fit another
explanation nearly as well. On a one-joint arm a loadcell offset on one muscle and a
heavier or lighter forearm move the same torque (``G_j(θ)·b`` against ``β·τ(θ)``: two
smooth functions of one angle); a motor whose temperature follows its load makes a thermal
drift a gain error on that loadcell; a gain common to the loadcells that carry a link
scales like that link's mass. Naming one with a p-value of 10⁻⁵⁷ claims a certainty the
recording does not hold.

The rule (``judge``): for a named effect A and every other candidate effect B — B's own
best units found by the same screen on the model without A, and, for effects that act per
muscle, B on A's muscles (a drift's load-dependent rivals: a gain or an offset on the
same loadcell) — refit B in A's place. B is a rival if it explains the mismatch by itself
(its likelihood-ratio test against the model without A passes, p < ``P_VALUE`` and
ΔBIC > 0). A survives B only if what A adds *beside* B passes what naming asks of any
effect, in-sample and held out: the likelihood ratio of (A + B) against B at
p < ``P_VALUE`` with ΔBIC > 0, and, on five-fold held-out rows, the drop of the whitened
squared residual summed over rows and channels — the held-out likelihood ratio — past the
same χ² threshold. That is the backward check the
selection applies to effects it has named, applied to the explanations it did not pick.
Nor does A survive B when B takes over all but ``RIDGE_SHARE`` of A's likelihood ratio
and fitting them together widens the standard error of A's amount more than
``MAX_INFLATION``-fold: what A adds beside B then lies along a direction the recording
barely holds, where the models' approximations decide (``inflation``). A gain on every
loadcell is always among a mass's rivals (one amplifier's gain scales every torque the
muscles make, as a heavier arm does). An A with rivals is reported as "either A or B …",
never named alone.

Why not a margin on the two fits' likelihoods: on the elbow with an offset on the long
triceps and another routing, the lighter forearm fits ΔBIC 18 better than the offset
(nominally "very strong", a Bayes factor of 8000) and is wrong; the model's own
approximations (a learned body schema, a fitted gravity function) move likelihoods by tens
of units. Why the held-out likelihood ratio and not the selection's paired z: beside the
offset the forearm adds an in-sample ratio of 26 (passes) but 22 held out (fails); when
the evidence sits in a few designed poses the paired z cannot exceed about √(rows that
carry it) (the elbow's settling session: held-out ratio 198, z 3.1). Numbers and the rules
tried: docs/diagnosis-notebook.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from pimbs_learn.diagnosis.fit import cross_validate, fit_effects
from pimbs_learn.diagnosis.inputs import MIN_SAMPLES, moved_less
from pimbs_learn.diagnosis.model import (
    EFFECTS,
    SPRING,
    Fit,
    Physics,
    Samples,
    Unit,
    evaluate,
    factors_not_positive,
    hysteresis,
    units_of,
)
from pimbs_learn.diagnosis.select import P_VALUE, UNIT_Z, Candidate, screen

PER_MUSCLE = ("tension_offset", "tension_gain", "thermal_drift", "tendon_friction",
              "elastic_stiffness")


@dataclass
class Rival:
    """Another explanation B of what the named effect A explains."""

    effect: str
    units: list[Unit]
    fit: Fit             # the model without A, with B in its place
    lr: float            # B against the model without A
    df: int
    lr_named_given: float  # A's likelihood ratio given B (A + B against B)
    lr_given_named: float  # B's likelihood ratio given A (A + B against A)
    delta_bic: float     # B's ΔBIC against the model without A
    heldout: Heldout | None = None  # adding A to B on held-out rows (None: not tested)
    inflation: float = 1.0  # how much fitting B beside A widens the error of A's amount
    ridge: bool = False     # A's ratio beside B discounted: B takes it over along a ridge


@dataclass
class Verdict:
    """What the recording says of one named effect."""

    named: Candidate
    fit: Fit               # the final model, with A
    without: Fit           # the final model without A
    lr: float              # A against the model without it (given the other named effects)
    delta_bic: float
    rivals: list[Rival]
    # (effect, units, per-recording likelihood ratio of A over B): recordings that disagree
    contradictions: list = field(default_factory=list)
    # A passes only with the loadcell branches guessed where the readings cannot tell them
    branch_bound: bool = False
    # A's units whose factor 1 + p the fit does not hold above zero (``factors_not_positive``)
    impossible: list[Unit] = field(default_factory=list)
    # a passive joint spring, outside the vocabulary, that explains what A does clearly
    # better (``outside_rival``, ``SPRING_MARGIN``): A is then not named
    outside: Rival | None = None
    # ... one that explains it about as well: A is named, the spring said beside it
    spring_alike: Rival | None = None

    @property
    def identified(self) -> bool:
        return (not self.rivals and not self.contradictions and not self.branch_bound
                and not self.impossible and self.outside is None)


def passes(lr: float, df: int, n: int) -> bool:
    """The test every named effect passes: LR at p < ``P_VALUE`` and a positive ΔBIC."""
    return bool(chi2.sf(lr, df) < P_VALUE and lr - df * np.log(n) > 0)


@dataclass
class Heldout:
    """How ``larger`` predicts held-out rows against ``smaller`` (five-fold, as selected)."""

    gain: float      # relative drop of the mean whitened squared residual
    lr: float        # held-out likelihood ratio: Σ over rows and channels of that drop
    z: float         # paired z of the per-row drops (reported, not a gate)
    improved: float  # share of rows predicted better (reported)
    df: int = 1

    @property
    def confirmed(self) -> bool:
        """Better on rows the fit never saw by as much as the naming test asks in-sample: a
        held-out likelihood ratio past the same χ² threshold. (Not also the selection's 1 %
        held-out gain: measured against a rival that already explains most of the mismatch,
        1 % of a 400-row, 15-channel recording is a ratio of about 60 — the 5-DOF arm's 4 N
        offset beside a drift had 83 held out and failed only that.)"""
        return self.lr >= chi2.isf(P_VALUE, self.df)


# A's amount's standard error widened this much by fitting B beside it: the estimates
# correlate beyond 0.995, and what A adds beside B lies along a direction the recording
# barely holds.
MAX_INFLATION = 10.0
# ... while B takes over all but this share of A's likelihood ratio: what is left beside B
# is then of the size the models' approximations make on a mismatch this large.
RIDGE_SHARE = 0.1


def inflation(alone: Fit, both: Fit, units: list[Unit]) -> float:
    """How much fitting B beside A widens the standard error of A's amount: of A's
    parameters along the direction of their estimate in ``alone`` (A without B), the
    error in ``both`` (A and B together) over the error in ``alone``.

    Where A and B move the data almost alike (a gain on every loadcell of a joint and a
    mass that joint carries scale the same torques), their joint fit slides along a ridge:
    on a drawn 2-DOF arm A's estimate moved by 800 standard errors and its error widened
    290-fold, and the likelihood ratio that still favoured A beside B (43, p 4·10⁻¹⁰) came
    from how the models approximate the lengths, not from the arm. Such a pair is reported
    as "either" when B also takes over nearly all of A's ratio (``RIDGE_SHARE``). The
    direction matters for effects of several parameters: a forearm's mass beside a gain on
    every loadcell widened one of its five parameters (a share of a proximal level) 52-fold
    but its amount 4.4-fold, and the mass is what the arm had."""
    if alone.cov is None or both.cov is None:
        return 1.0
    ia = [alone.units.index(u) for u in units]
    ib = [both.units.index(u) for u in units]
    d = alone.params[ia] / max(float(np.linalg.norm(alone.params[ia])), 1e-300)
    var_alone = float(d @ alone.cov[np.ix_(ia, ia)] @ d)
    var_both = float(d @ both.cov[np.ix_(ib, ib)] @ d)
    return float(np.sqrt(max(var_both, 0.0) / max(var_alone, 1e-300)))


def heldout(physics: Physics, data: Samples, smaller: Fit, larger: Fit) -> Heldout:
    """Held-out test of ``larger`` over ``smaller``, both on ``smaller``'s noise scale (so
    the summed drop of whitened squared residuals is a likelihood ratio with the noise
    levels held)."""
    sigma = (smaller.sigma_len, smaller.sigma_tau)
    before = cross_validate(physics, data, smaller.units, sigma, x0=smaller.params)
    after = cross_validate(physics, data, larger.units, sigma, x0=larger.params)
    d = before["per_sample"] - after["per_sample"]
    z = d.mean() / max(d.std(ddof=1) / np.sqrt(len(d)), 1e-300)
    return Heldout(float(1.0 - after["score"] / before["score"]), float(d.sum()), float(z),
                   float(np.mean(d > 0)), len(larger.units) - len(smaller.units))


def _sub(fit: Fit, units: list[Unit]) -> np.ndarray:
    return np.array([fit.params[fit.units.index(u)] for u in units])


def _lr(a: Fit, b: Fit) -> float:
    return max(2.0 * (a.log_lik - b.log_lik), 0.0)


def rival_unit_sets(physics: Physics, data: Samples, without: Fit, named: Candidate,
                    effect: str) -> list[list[Unit]]:
    """B's own best units on the model without A, and B on A's muscles (per-muscle effects)."""
    sets = []
    own = screen(physics, data, without, effect)
    if own:
        sets.append(own)
    if named.effect in PER_MUSCLE and effect in PER_MUSCLE:
        muscles = sorted({u.index for u in named.units if u.index >= 0})
        same = [Unit(effect, j) for j in muscles if Unit(effect, j) not in without.units]
        if same and set(same) != set(own):
            sets.append(same)
    n_muscles = data.tension.shape[1]
    if effect == "link_mass" and not own:
        # one subtree is what a mass can be: the whole arm, the screen's usual first pick;
        # of the file's links, the last, whose weight every joint carries
        groups = units_of(effect, physics, data)
        group = groups[-1] if physics.links else groups[0]
        if not any(u in without.units for u in group):
            sets.append(group)
    if effect == "tension_gain" and named.effect == "link_mass":
        # one amplifier's gain on every loadcell scales every torque the muscles make, as a
        # heavier arm does: the screen, adding muscles one at a time, may stop short of it
        common = [Unit(effect, j) for j in range(n_muscles) if Unit(effect, j)
                  not in without.units]
        if common and all(set(common) != set(s) for s in sets):
            sets.append(common)
    return sets


def unsure_branches(data: Samples, final: Fit) -> np.ndarray | None:
    """(B, M) rows whose loadcell branch the readings cannot tell, or None (no hysteresis
    fitted, or every branch told).

    A loadcell's branch is read from the change of its reading into the row
    (``inputs.collection_order``). That change is the tension's change plus the reading
    noise, plus, where the branch flipped, the jump 2h between the branches against it: a
    change smaller than 2h past the dead band may come from a flip or from none."""
    h = hysteresis(final)
    if data.branch is None or data.prev_tension is None or not h:
        return None
    unsure = moved_less(data, h)
    return unsure if unsure.any() else None


def branch_bound(physics: Physics, data: Samples, final: Fit, named: Candidate) -> bool:
    """Whether ``named`` passes the naming test only with the loadcell branches guessed
    where the readings cannot tell them.

    On a recording whose tensions barely move (a first session near the middle of the
    ranges, every muscle at its floor) most rows' branches are guesses, and a wrong guess
    on one row in seven leaves ±2h that follows the direction each wire last moved: a
    stiffness change or an offset on that loadcell then fits it, on arms with nothing wrong
    (docs/diagnosis-notebook.md). So each muscle of an effect that acts per loadcell is
    refitted, with and without it, on the rows whose branch of that loadcell is told: a
    muscle that fails there (or has too few such rows to name anything) rests on the
    guesses, not on the arm. Effects of joints and links are not judged this way, nor
    any effect on a recording that shows no hysteresis (its fit does not pass the naming
    test against the same model without it)."""
    unsure = unsure_branches(data, final)
    if unsure is None or named.effect not in PER_MUSCLE:
        return False
    keep = [u for u in final.units if u.effect != "loadcell_hysteresis"]
    no_hysteresis = fit_effects(physics, data, keep, x0=_sub(final, keep), key="full")
    if not passes(_lr(final, no_hysteresis), 1, data.n):
        return False  # no hysteresis the recording shows: a wrong branch costs nothing
    for unit in named.units:
        if unit.index < 0:
            continue
        sure = np.flatnonzero(~unsure[:, unit.index])
        if len(sure) < MIN_SAMPLES:
            return True
        rows = data.rows(sure)
        keep = [u for u in final.units if u != unit]
        with_a = fit_effects(physics, rows, final.units, x0=final.params)
        without_a = fit_effects(physics, rows, keep, x0=_sub(final, keep))
        if not passes(_lr(with_a, without_a), 1, rows.n):
            return True
    return False


def spring_units(joint: int) -> list[Unit]:
    """A spring at ``joint``: its rate and its torque at the description's zero."""
    return [Unit(SPRING, joint, "rate"), Unit(SPRING, joint, "torque")]


def outside_rival(physics: Physics, data: Samples, final: Fit, without: Fit, named: Candidate
                  ) -> Rival | None:
    """A passive spring at one joint (``model.SPRING``) that explains what A does, or None.

    A cover, a cable bundle or a joint's stop pulls a joint toward one angle, and no effect
    of the vocabulary is that: the selection then names whatever follows the pull best. On
    MuJoCo plants whose only change was a joint spring, a loadcell gain on that joint's
    muscles was named on four drawn arms (a spring's torque grows as the joint leaves its
    rest, and so does the tension the muscles hold against it). A spring fitted in the
    gain's place recovered the plant's rate within 2.5 %, with a likelihood ratio 1.07–5.9
    times the gain's, and the gain added nothing beside it (docs/diagnosis-notebook.md).

    The spring at the joint where it fits best in A's place explains what A does when it
    passes the naming test against the model without A, its rate restores (above zero by
    ``UNIT_Z`` standard errors: a joint pushed away from an angle is no spring), and A adds
    nothing beside it that the naming test and the held-out rows confirm. Whether it then
    takes A's place is ``judge``'s to say (``SPRING_MARGIN``).
    """
    n = data.n
    best = None
    for joint in range(data.theta.shape[1]):
        units = spring_units(joint)
        fit_b = fit_effects(physics, data, [*without.units, *units], key="full",
                            x0=np.append(without.params, np.zeros(2)))
        lr_b = _lr(fit_b, without)
        if best is None or lr_b > best[2]:
            best = (units, fit_b, lr_b)
    units, fit_b, lr_b = best
    rate = fit_b.units.index(units[0])
    se = np.sqrt(fit_b.cov[rate, rate]) if fit_b.cov is not None else np.inf
    if not passes(lr_b, 2, n) or not fit_b.params[rate] > UNIT_Z * se:
        return None
    both = fit_effects(physics, data, [*without.units, *named.units, *units], key="full",
                       x0=np.concatenate([without.params, _sub(final, named.units),
                                          _sub(fit_b, units)]))
    a_given_b = _lr(both, fit_b)
    held = None
    if passes(a_given_b, len(named.units), n):
        held = heldout(physics, data, fit_b, both)
        if held.confirmed:
            return None
    return Rival(SPRING, units, fit_b, lr_b, 2, a_given_b, _lr(both, final),
                 lr_b - 2 * np.log(n), held)


# A spring that explains what A does takes A's place only when its ΔBIC is beyond A's by
# the naming test's one-parameter threshold. A mass change on the first link moves that
# joint's torque by a sine of its angle, which a spring follows nearly as well over a
# joint's range (on drawn arms: likelihood ratios of 549.5 against 550.0, 194.5 against
# 191.1): outside the vocabulary, a spring does not take a name it only matches; the name
# is kept and the spring said beside it (``Verdict.spring_alike``). The margin's cost, as
# judged: a heavier second link on PIMBS's simulator, which has no springs, was taken by a
# spring 25 ahead (docs/diagnosis-notebook.md).
SPRING_MARGIN = float(chi2.isf(P_VALUE, 1))


def springs_in_place(physics: Physics, data: Samples, final: Fit, verdicts: list[Verdict]
                     ) -> Fit:
    """``final`` with each name a joint spring took (``Verdict.outside``) replaced by that
    spring, refitted: what is left beside it is what nothing explains."""
    sprung = [v for v in verdicts if v.outside is not None]
    if not sprung:
        return final
    gone = {u for v in sprung for u in v.named.units}
    keep = [u for u in final.units if u not in gone]
    start: dict[Unit, float] = {}  # each spring from the first fit that had it
    for v in sprung:
        for u, p in zip(v.outside.units, _sub(v.outside.fit, v.outside.units), strict=True):
            start.setdefault(u, p)
    return fit_effects(physics, data, [*keep, *start], key="full",
                       x0=np.concatenate([_sub(final, keep), list(start.values())]))


def judge(physics: Physics, data: Samples, final: Fit, named: Candidate,
          effects: tuple[str, ...] = EFFECTS) -> Verdict:
    """Refit every other candidate effect in ``named``'s place; keep those it cannot beat
    (none are sought for a name that rests on guessed loadcell branches, ``branch_bound``,
    on a factor no arm has, ``factors_not_positive``, or that a joint spring explains
    better, ``outside_rival``)."""
    keep = [u for u in final.units if u not in named.units]
    without = fit_effects(physics, data, keep, x0=_sub(final, keep), key="full")
    n, df_a = data.n, len(named.units)
    lr_a = _lr(final, without)
    bic_a = lr_a - df_a * np.log(n)
    if branch_bound(physics, data, final, named):
        return Verdict(named, final, without, lr_a, bic_a, [], branch_bound=True)
    impossible = factors_not_positive(final, named.units, UNIT_Z)
    if impossible:
        return Verdict(named, final, without, lr_a, bic_a, [], impossible=impossible)
    spring = outside_rival(physics, data, final, without, named)
    if spring is not None and spring.delta_bic - bic_a > SPRING_MARGIN:
        return Verdict(named, final, without, lr_a, bic_a, [], outside=spring)
    rivals, contradictions = [], []
    for effect in effects:
        if effect == named.effect:
            continue
        best = None
        for units in rival_unit_sets(physics, data, without, named, effect):
            fit_b = fit_effects(physics, data, [*keep, *units], key="full",
                                x0=np.append(without.params, np.zeros(len(units))))
            lr_b = _lr(fit_b, without)
            if passes(lr_b, len(units), n) and (best is None or lr_b > best[2]):
                best = (units, fit_b, lr_b)
        if best is None:
            continue
        units, fit_b, lr_b = best
        both_units = [*keep, *named.units, *units]
        both = fit_effects(physics, data, both_units, key="full",
                           x0=np.concatenate([_sub(final, keep + named.units),
                                              _sub(fit_b, units)]))
        a_given_b = _lr(both, fit_b)
        split = by_recording(physics, data, final, fit_b)
        if split is not None:
            contradictions.append((effect, units, split))
        held = None
        wider = inflation(final, both, named.units)
        ridge = wider > MAX_INFLATION and a_given_b < RIDGE_SHARE * lr_a
        if passes(a_given_b, df_a, n) and not ridge:
            held = heldout(physics, data, fit_b, both)
            if held.confirmed:
                continue  # A adds to B what B cannot explain: B is no confounder of A
        rivals.append(Rival(effect, units, fit_b, lr_b, len(units), a_given_b,
                            _lr(both, final), lr_b - len(units) * np.log(n), held, wider,
                            ridge))
    rivals.sort(key=lambda r: -r.lr)
    return Verdict(named, final, without, lr_a, bic_a, rivals, contradictions,
                   spring_alike=spring)


def by_recording(physics: Physics, data: Samples, fit_a: Fit, fit_b: Fit) -> list[float] | None:
    """Per recording, how much better ``fit_a`` explains its rows than ``fit_b`` (a
    likelihood ratio with ``fit_a``'s noise levels held) — when one recording prefers each
    by more than the naming test accepts, else None.

    Recordings of one arm must agree on what is wrong with it. When a session designed to
    separate A from B prefers B while the first prefers A, the models cannot represent the
    arm on one of them (the elbow with another routing: its learned body schema leaves a
    torque error of half the mismatch whatever the explanation), and naming either would
    follow whichever session has more rows.
    """
    if data.session is None or len(np.unique(data.session)) < 2:
        return None
    sq = []
    for fit in (fit_a, fit_b):
        r_len, r_tau = evaluate(physics, fit, data)
        sq.append(np.sum(np.hstack([r_len / fit_a.sigma_len, r_tau / fit_a.sigma_tau]) ** 2,
                         axis=1))
    d = sq[1] - sq[0]
    per = [float(d[data.session == s].sum()) for s in np.unique(data.session)]
    need = chi2.isf(P_VALUE, 1)
    return per if max(per) >= need and min(per) <= -need else None
