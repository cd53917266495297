"""The poses that would tell two explanations apart (optimal experiment design).

When the recording fits effect A and its rival B alike (``confound``), the question is
which poses, held with which tensions, make their predictions differ most — and differ in
a way the rival's parameters cannot follow once those poses are in the data. Both are
fitted models; each predicts what the arm would report at any pose:

1. **Candidates**: feasible poses of the seeded plan (``pimbs_arm.poses``), each with three
   tension floors — its ATL draw, every muscle at its ``f_floor`` (an offset shows in the
   stretch of a slack muscle) and every muscle high (a gain grows with the tension, an
   offset does not). Each is checked by the tension QP within the plan's ceiling.
2. **Predictions**: the arm description with each explanation concealed in it (all effects
   of that fitted model, as ``pimbs_sim`` conceals them) is simulated at every candidate,
   noise-free: what the next session would record if that explanation were true.
3. **Criterion** (T-optimality, Atkinson & Fedorov 1975): if A is true, the rows S add to
   B's best residual sum of squares (whitened by the noise levels, i.e. the expected
   likelihood ratio in favour of A)
   ``Δ_AB(S) = Σ_S |e_i|² − bᵀ (I_B + Σ_S J_iᵀJ_i)⁻¹ b``, ``b = Σ_S J_iᵀ e_i``,
   where ``e_i`` is B's residual on A's prediction (minus B's residual on its own
   prediction, so what the model gets wrong either way — the description's routing against
   the real arm's — cancels), ``J_i`` its derivative in B's parameters and ``I_B`` the
   information the first recording already holds on them: B may refit, as it will. So
   may the new session's length constant per muscle (each session homes its motors
   anew; the first recording holds nothing of it): a difference that is the same in every
   chosen row's length — a loadcell gain's stretch with every muscle held high — tells
   nothing. The design maximises ``min(Δ_AB, Δ_BA)`` over every rival, greedily, pose by
   pose.

Predictions use the model's routing and, for a link mass, the file's links as the diagnosis
fitted them (``link_masses``), so the expected likelihood ratio is a guide; the combined
diagnosis is the judge.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pimbs_arm.model import ArmModel
from pimbs_arm.poses import PosePlan, atl_floor_range, feasible, plan_poses
from pimbs_arm.poses_file import pose_plan_csv
from pimbs_learn.diagnosis.confound import Verdict
from pimbs_learn.diagnosis.inputs import BRANCH_DEADBAND, stretch_weights
from pimbs_learn.diagnosis.model import (
    SENSOR,
    SPRING,
    Fit,
    Physics,
    Samples,
    Unit,
    apply_effects,
    evaluate,
    fit_schema,
    hysteresis,
)
from pimbs_learn.diagnosis.robot_file import link_torques
from pimbs_learn.diagnosis.select import FD_STEP, _whitened, fd_column
from pimbs_sim.effects import T_REF, Effect
from pimbs_sim.simulate import simulate

POOL = 120          # candidate poses, each with three tension floors
POOL_SEED = 7919    # the candidates' seed: one plan for one arm, whatever the recording
# the sensors' noise the designs assume where the diagnosis gives no estimate of its own
NOISE = {"tension_N": 0.3, "length_m": 5e-6}


def candidate_pool(arm: ArmModel, n: int = POOL, seed: int = POOL_SEED) -> PosePlan:
    """Feasible poses with their ATL floors, all floors low, and all floors high."""
    plan = plan_poses(arm, n, seed, "atl")
    f_floor = np.array([m.f_floor for m in arm.robot.muscles])
    high = np.full(arm.n_muscles, atl_floor_range(arm)[1])
    poses, floors = [], []
    for theta, drawn in zip(plan.poses, plan.drawn_floors, strict=True):
        for f in (drawn, np.zeros(arm.n_muscles), high):
            if feasible(arm, theta, np.maximum(f, f_floor)):
                poses.append(theta)
                floors.append(f)
    # as a poses file gives them: the floors the collection holds (≥ each f_floor)
    floors = np.maximum(np.array(floors), f_floor)
    return PosePlan(poses=np.array(poses), floors=floors, drawn_floors=floors, replaced=())


def pool_within(arm: ArmModel, theta: np.ndarray, n: int = POOL, seed: int = POOL_SEED
                ) -> PosePlan:
    """Feasible poses drawn in the box of joint angles ``theta`` (rows) covers, each with
    every floor low, at half the ATL-Map's top and at its top: the same body the recording
    saw, at tensions that step far from one another. Empty where none can be held."""
    rng = np.random.default_rng(seed)
    lo, hi = np.min(theta, axis=0), np.max(theta, axis=0)
    f_floor = np.array([m.f_floor for m in arm.robot.muscles])
    top = atl_floor_range(arm)[1]
    levels = [np.zeros(arm.n_muscles), np.full(arm.n_muscles, top / 2),
              np.full(arm.n_muscles, top)]
    poses, floors = [], []
    for _ in range(20 * n):
        if len(poses) >= 3 * n:
            break
        pose = rng.uniform(lo, hi)
        for f in levels:
            f = np.maximum(f, f_floor)
            if feasible(arm, pose, f):
                poses.append(pose)
                floors.append(f)
    shape = (0, arm.n_muscles)
    floors_arr = np.array(floors) if floors else np.zeros(shape)
    return PosePlan(poses=np.array(poses) if poses else np.zeros((0, arm.n_joints)),
                    floors=floors_arr, drawn_floors=floors_arr, replaced=())


# the order :func:`concealed` conceals the rest in (a link-mass change comes first, from
# :func:`link_masses`)
ORDER = (SPRING, "elastic_stiffness", "joint_offset", "tendon_friction", "tension_gain",
         "tension_offset", "thermal_drift")


def link_masses(units: list[Unit], params: np.ndarray, arm: ArmModel, physics: Physics,
                theta: np.ndarray) -> tuple[Effect, ...]:
    """The fitted link-mass change as the simulator conceals it: one mass scale per link.

    A unit on one of the robot file's links is that link's scale. Without the file's links
    the fit spreads a mass change over the links beyond a joint (one scale) and its own
    share of each proximal level of the gravity potential (a heavier upper arm is the
    latter on a forearm's unit); it is matched, by least squares at the poses ``theta``,
    to one scale per link the joints carry. Scaling only the link the unit's joint carries
    would simulate another explanation than the one fitted, and the poses would be chosen
    to separate that one."""
    fit = [(u, float(p)) for u, p in zip(units, params, strict=True) if u.effect == "link_mass"]
    own = tuple(Effect("link_mass", max(1.0 + p, 1e-3), link=physics.links[u.index])
                for u, p in fit if u.part == "link")
    extra = np.zeros(physics.gravity.coef.shape)
    for u, p in fit:
        if u.part != "link":
            extra += p * (physics.gravity.distal_split(u.index)[0] if u.part == "distal"
                          else physics.gravity.level(int(u.part.removeprefix("level"))))
    if not np.any(extra):
        return own
    names, torques = link_torques(arm, theta)
    if not names:
        return own
    target = physics.gravity.torque(theta, extra)
    scale, *_ = np.linalg.lstsq(torques.reshape(len(names), -1).T, target.ravel(), rcond=None)
    return own + tuple(Effect("link_mass", max(1.0 + float(s), 1e-3), link=link)
                       for link, s in zip(names, scale, strict=True) if abs(s) > 1e-6)


def concealed(units: list[Unit], params: np.ndarray, arm: ArmModel,
              masses: tuple[Effect, ...] = ()) -> tuple[Effect, ...]:
    """The fitted effects as the simulator conceals them: the arm's physics first (the
    link-mass change as :func:`link_masses` matched it: ``masses``), then the loadcell chain
    in order."""
    out = list(masses)
    fitted = [(u, p) for u, p in zip(units, params, strict=True)
              if u.effect not in (*SENSOR, "link_mass")]
    value = {u: float(p) for u, p in fitted}
    for u, p in sorted(fitted, key=lambda x: ORDER.index(x[0].effect)):
        p = float(p)
        muscles = () if u.part == "common" else (arm.muscles[u.index],)
        if u.effect == SPRING and u.part == "rate":  # the muscles hold rate·θ + torque
            torque = value.get(Unit(SPRING, u.index, "torque"), 0.0)
            out.append(Effect(SPRING, p, joints=(arm.joints[u.index],),
                              extra={"rest": -torque / p}))
        elif u.effect == SPRING:
            continue  # the spring's torque at zero: its rest angle, above
        elif u.effect == "elastic_stiffness":
            out.append(Effect("elastic_stiffness", 1.0 / max(1.0 + p, 1e-3), muscles=muscles))
        elif u.effect == "joint_offset":
            out.append(Effect("joint_offset", p, joints=(arm.joints[u.index],)))
        else:
            out.append(Effect(u.effect, p, muscles=muscles))
    return tuple(out)


def predict(arm: ArmModel, pool: PosePlan, fit: Fit | None, physics: Physics, noise: dict
            ) -> Samples:
    """What a session at the pool's poses records if ``fit``'s explanation is true (None:
    the description itself)."""
    n = len(pool.poses)
    effects = () if fit is None else concealed(
        fit.units, fit.params, arm, link_masses(fit.units, fit.params, arm, physics, pool.poses))
    data, _ = simulate(arm, n, "atl", effects=effects, noise=0.0, poses=pool)
    t = data["time"].astype("datetime64[us]").astype(np.int64) / 1e6
    out = Samples(theta=data["theta"], tension=data["tension"], length=data["length"],
                  temperature=data["temperature"], approach=data["approach"].astype(float),
                  tau=data["tau_gravity"], time=t - t[0], sample=data["sample"],
                  temp_zero=np.full((n, arm.n_muscles), T_REF))
    out.len_weight = stretch_weights(physics.kappa, out.tension, noise["tension_N"],
                                     noise["length_m"])
    return out


def _rows(physics: Physics, fit: Fit, data: Samples, params: np.ndarray | None = None
          ) -> np.ndarray:
    """(rows, channels) whitened residuals of ``fit`` (schema held) on ``data``."""
    f = fit if params is None else fit.with_params(params)
    r_len, r_tau = evaluate(physics, f, data)
    return np.hstack([r_len / fit.sigma_len, r_tau / fit.sigma_tau])


class _Test:
    """How the rows picked so far would reject ``rival`` if the other explanation were true.

    ``own``/``other``: the predictions of the rival and of the other explanation;
    ``described``: the physics with the description's body schema, which produced both
    (the real arm's learned schema would add the routing difference to every row).
    """

    def __init__(self, physics: Physics, described: Physics, schema: np.ndarray,
                 data: Samples, rival: Fit, own: Samples, other: Samples):
        model = replace(rival, weights=schema)
        base = _rows(described, model, other)
        self.e = base - _rows(described, model, own)  # (R, C)
        cols = []
        for i, u in enumerate(rival.units):
            p = rival.params.copy()
            p[i] += FD_STEP[u.effect]
            cols.append((_rows(described, model, other, p) - base) / FD_STEP[u.effect])
        j = np.stack(cols, axis=2) if cols else np.zeros((*self.e.shape, 0))  # (R, C, P)
        sigma = (rival.sigma_len, rival.sigma_tau)
        r0 = _whitened(physics, data, rival.units, rival.params, sigma)
        old = np.stack([fd_column(physics, data, rival, u, r0, sigma) for u in rival.units],
                       1) if rival.units else np.zeros((len(r0), 0))
        w = (np.ones((len(j), rival.sigma_len.size)) if other.len_weight is None
             else other.len_weight)
        self._set(self.e, j, old.T @ old, w / rival.sigma_len)

    def _set(self, e: np.ndarray, j: np.ndarray, info: np.ndarray, homing: np.ndarray
             ) -> None:
        """``e`` (R, C) and ``j`` (R, C, P) as above, ``info`` (P, P); ``homing`` (R, M):
        the whitened length channels' scale. The new session homes its motors anew, so a
        length constant of its own per muscle (the first M channels), of which the first
        recording says nothing, is refitted with the rival."""
        m = homing.shape[1]
        const = np.zeros((*e.shape, m))
        const[:, np.arange(m), np.arange(m)] = -homing
        self.e, self.j = e, np.concatenate([j, const], axis=2)
        self.info = np.zeros((j.shape[2] + m,) * 2)
        self.info[:j.shape[2], :j.shape[2]] = info
        self.ee = np.einsum("rc,rc->r", self.e, self.e)
        self.je = np.einsum("rcp,rc->rp", self.j, self.e)
        self.jj = np.einsum("rcp,rcq->rpq", self.j, self.j)

    def gain(self, chosen: list[int]) -> np.ndarray:
        """Δ for ``chosen`` plus each candidate row (R,)."""
        s_ee = self.ee[chosen].sum() if chosen else 0.0
        s_je = self.je[chosen].sum(0) if chosen else np.zeros(self.je.shape[1])
        s_jj = self.info + (self.jj[chosen].sum(0) if chosen else 0.0)
        b = s_je[None, :] + self.je
        a = s_jj[None, :, :] + self.jj
        ridge = 1e-9 * np.maximum(np.trace(a, axis1=1, axis2=2), 1e-300)[:, None, None]
        a = a + ridge * np.eye(a.shape[1])[None]
        quad = np.einsum("rp,rp->r", b, np.linalg.solve(a, b[:, :, None])[:, :, 0]) \
            if a.shape[1] else 0.0
        return s_ee + self.ee - quad


def _described(arm: ArmModel, pool: PosePlan, physics: Physics, noise: dict
               ) -> tuple[Physics, Samples, np.ndarray]:
    """The physics the predictions are scored with, a clean session at the pool's poses,
    and the body schema fitted on it: the description's own (the predictions come from
    it), one recording, no routing tied to the real arm's."""
    described = replace(physics, tied=None, recordings=1, _cache={})
    clean = predict(arm, pool, None, physics, noise)
    return described, clean, fit_schema(
        described, apply_effects(described, clean, [], np.zeros(0)), clean)


def gentle_order(pred: Samples, rows: list[int], noise: dict) -> list[int]:
    """``rows`` in the order a session should hold them: each next the one whose readings
    (``pred``, in units of the sensors' noise) differ least from the last, from the one
    nearest home and unloaded.

    Why: every board reads through a filter and every loadcell has hysteresis, so a share
    of the previous reading and a branch set by the last change stay in each row. The
    chosen poses are extremes, and held in the order chosen they alternate (the arm swung
    from one end of a range to the other), which leaves the most of the previous pose in
    each reading: a lag that scales the readings much as a loadcell gain does. In a gentle
    order the readings carry little of it, and what separates the explanations stays."""
    y = np.hstack([pred.tension[rows] / noise["tension_N"], pred.length[rows] / noise["length_m"]])
    left = list(range(len(rows)))
    order = [min(left, key=lambda i: float(np.sum(y[i] ** 2)))]
    left.remove(order[0])
    while left:
        nxt = min(left, key=lambda i: float(np.sum((y[i] - y[order[-1]]) ** 2)))
        order.append(nxt)
        left.remove(nxt)
    return [rows[i] for i in order]


def separating_poses(arm: ArmModel, physics: Physics, data: Samples, verdict: Verdict,
                     k: int, noise: dict | None = None) -> dict:
    """The ``k`` poses (and floors) that best tell the named effect from its rivals."""
    noise = noise or NOISE
    pool = candidate_pool(arm)
    models = [verdict.fit, *(r.fit for r in verdict.rivals)]
    preds = [predict(arm, pool, m, physics, noise) for m in models]
    described, _, schema = _described(arm, pool, physics, noise)
    tests = []
    for b in range(1, len(models)):  # the named against each rival, either way true
        for rival, truth in ((b, 0), (0, b)):
            tests.append(_Test(physics, described, schema, data, models[rival], preds[rival],
                               preds[truth]))
    chosen: list[int] = []
    score = 0.0
    for _ in range(min(k, len(pool.poses))):
        worst = np.min([t.gain(chosen) for t in tests], axis=0)
        worst[chosen] = -np.inf
        best = int(np.argmax(worst))
        chosen.append(best)
        score = float(worst[best])
    chosen = gentle_order(preds[0], chosen, noise)
    floors = pool.floors[chosen]
    names = [verdict.named.effect, *(r.effect for r in verdict.rivals)]
    return {"between": names, "poses": pool.poses[chosen].tolist(),
            "floors_N": floors.tolist(), "expected_likelihood_ratio": score,
            "meaning": "poses (rad, joint order) and tension floors (N, muscle order) whose "
                       "predicted readings differ most between the explanations, beyond what "
                       "each one's parameters can follow; the expected likelihood ratio is "
                       "that of the true one against the best other after collecting them",
            "csv": pose_plan_csv(arm, pool.poses[chosen], floors)}


def branch_telling_poses(arm: ArmModel, physics: Physics, data: Samples, verdict: Verdict,
                         k: int, noise: dict | None = None) -> dict:
    """The ``k`` poses (and floors) that settle a name resting on guessed loadcell branches
    (``confound.branch_bound``), or on a factor no arm has (``model.factors_not_positive``): the
    wire's stretch taken up where its tension follows its pose, which the same steps of
    tension show apart from the pose.

    Its rival is the same model without it, the loadcells' hysteresis left to explain the
    mismatch: the poses are picked as ``separating_poses`` picks them (T-optimal, either
    way true), each next one among the candidates into which every muscle's tension changes
    by more than the hysteresis can hide (2ĥ plus the dead band, plus three noise levels,
    in a reading that itself jumps 2ĥ back where its branch flips), so that in the new
    session each row's branch is told, not guessed. The candidates lie
    in the joint box the recording covers (``pool_within``): what is in question is the
    loadcells, not the body, and poses beyond the recorded ones would ask the learned body
    schema to reach where it was never fitted. Their floors (all low, at half the ATL top,
    at the top) make such steps available from almost any pose; where none is, the pose
    whose smallest change is largest comes next."""
    noise = noise or NOISE
    pool = pool_within(arm, data.theta)
    if len(pool.poses) < k:  # the recording's box holds too few: the whole ranges
        pool = candidate_pool(arm)
    named, other = verdict.fit, verdict.without
    pred_a, pred_b = (predict(arm, pool, m, physics, noise) for m in (named, other))
    described, clean, schema = _described(arm, pool, physics, noise)
    tests = [_Test(physics, described, schema, data, other, pred_b, pred_a),
             _Test(physics, described, schema, data, named, pred_a, pred_b)]
    # a reading whose branch flips moves 2ĥ less than its tension: that change, past 2ĥ
    need = 4.0 * hysteresis(named) + BRANCH_DEADBAND + 3.0 * noise["tension_N"]
    tension = clean.tension
    chosen: list[int] = []
    score = 0.0
    for _ in range(min(k, len(pool.poses))):
        worst = np.min([t.gain(chosen) for t in tests], axis=0)
        worst[chosen] = -np.inf
        if chosen:
            step = np.abs(tension - tension[chosen[-1]]).min(axis=1)
            told = step >= need
            told[chosen] = False
            if told.any():
                worst[~told] = -np.inf
            else:
                worst = np.where(np.isfinite(worst), step, -np.inf)
        best = int(np.argmax(worst))
        chosen.append(best)
        score = float(np.min([t.gain(chosen[:-1])[best] for t in tests]))
    floors = pool.floors[chosen]
    rival, against = (("loadcell_hysteresis", "the hysteresis alone") if verdict.branch_bound
                      else ("body_schema", "the model without it"))
    return {"between": [verdict.named.effect, rival],
            "poses": pool.poses[chosen].tolist(), "floors_N": floors.tolist(),
            "expected_likelihood_ratio": score, "branch_step_N": need,
            "meaning": "poses (rad, joint order) and tension floors (N, muscle order), in the "
                       "order to collect them: every muscle's tension changes into each by "
                       "more than the loadcells' hysteresis can hide, so each reading's "
                       f"branch is told; picked to tell the effect from {against}",
            "csv": pose_plan_csv(arm, pool.poses[chosen], floors)}


def unseen_poses(arm: ArmModel, physics: Physics, data: Samples, k: int,
                 noise: dict | None = None) -> dict:
    """The ``k`` poses (and floors) farthest from every recorded row, for a rest that is not
    noise (``leftover``) and that no effect of the library accounts for.

    There is no rival to tell it from, so nothing to optimise a contrast on: what the
    recording lacks is range. A session held in a narrow box of poses at light tensions
    leaves an effect that only shows across the range (a drift that needs the motors
    loaded and rested) looking like an unnamed rest, where a wider session names it. The
    candidates are the whole plan's (``candidate_pool``: every joint's range, each wire at
    its drawn, low and high floor); each next pose is the one farthest from the recorded
    rows and the poses chosen so far (greedy max-min), in joint angles over each joint's
    span and tensions over the ATL-Map's top, each group weighed alike whatever the number
    of joints and muscles; they are held in a gentle order."""
    noise = noise or NOISE
    pool = candidate_pool(arm)
    clean = predict(arm, pool, None, physics, noise)
    span = np.maximum(np.ptp(np.vstack([pool.poses, data.theta]), axis=0), 1e-9)
    top = atl_floor_range(arm)[1]

    def where(theta: np.ndarray, tension: np.ndarray) -> np.ndarray:
        return np.hstack([theta / span / np.sqrt(theta.shape[1]),
                          tension / top / np.sqrt(tension.shape[1])])

    cand = where(pool.poses, clean.tension)
    near = np.min(np.linalg.norm(cand[:, None, :] - where(data.theta, data.tension)[None],
                                 axis=2), axis=1)
    chosen: list[int] = []
    for _ in range(min(k, len(pool.poses))):
        best = int(np.argmax(near))
        chosen.append(best)
        near = np.minimum(near, np.linalg.norm(cand - cand[best], axis=1))
        near[chosen] = -np.inf
    chosen = gentle_order(clean, chosen, noise)
    floors = pool.floors[chosen]
    return {"between": ["what is left", "the effects of the library"],
            "poses": pool.poses[chosen].tolist(), "floors_N": floors.tolist(),
            "expected_likelihood_ratio": None,
            "meaning": "poses (rad, joint order) and tension floors (N, muscle order), in the "
                       "order to collect them, farthest from the recorded ones: what is left "
                       "shows what it depends on where the recording has not been; there is "
                       "no rival to score, so no expected likelihood ratio",
            "csv": pose_plan_csv(arm, pool.poses[chosen], floors)}


def design_csv(result: dict) -> tuple[str, int]:
    """One poses file for every ambiguity of a diagnosis, every name that rests on guessed
    loadcell branches or on a factor no arm has, a name a joint spring fits as well, and a
    rest asked where the recording has not been (one session settles them all), and how
    many poses it holds."""
    entries = [*result.get("ambiguous", []), *result.get("unexplained", []),
               *(e["spring_fits_alike"] for e in result.get("effects", [])
                 if e.get("spring_fits_alike"))]
    rows = [a["separating_poses"]["csv"].splitlines() for a in entries
            if a.get("separating_poses")]
    if not rows:
        return "", 0
    body = [r for part in rows for r in part[1:]]
    return "\n".join([rows[0][0], *body]) + "\n", len(body)
