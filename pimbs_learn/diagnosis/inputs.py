"""Turning recordings (and optionally a robot description) into what the diagnosis fits.

The real recording carries almost everything: its own body schema is learned from it, and
``tau_gravity`` gives the model's gravity. The reference recording (the simulator's view
of the same commanded poses) or the robot description supplies what the real data cannot:
the modelled elasticity ``K`` (with the sign convention of whoever wrote the files), and
gravity where the real file has none.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from pimbs_learn.diagnosis.bases import GravityFunction, PolyBasis
from pimbs_learn.diagnosis.fit import choose_schema, fit_effects
from pimbs_learn.diagnosis.model import (
    Fit,
    Physics,
    Samples,
    Unit,
    apply_effects,
    evaluate,
    fit_schema,
    hysteresis,
    hysteresis_reversed,
    schema_jacobian,
    sensor_units,
)
from pimbs_learn.diagnosis.select import UNIT_Z
from pimbs_recording.format import Recording

DEFAULT_KAPPA = -1e-3  # start of the elasticity fit: K = 1000, physical sign
MIN_SAMPLES = 30  # paired rows below which physics cannot be told from noise


class DiagnosisInputError(ValueError):
    """Recordings that cannot be compared; the message names the files and what differs."""


BRANCH_DEADBAND = 1.0  # N: a smaller change of a reading leaves its loadcell on its branch
BRANCH_NOISE = 3.0  # σ of a steady loadcell's changes: a change within them may be noise


def samples_from(rec: Recording, tau: np.ndarray | None = None) -> Samples:
    t = rec.time.astype("datetime64[us]").astype(np.int64) / 1e6
    prev_tension, prev_length, branch, deadband = collection_order(t, rec.tension, rec.length)
    return Samples(theta=rec.theta, tension=rec.tension, length=rec.length,
                   temperature=rec.temperature, approach=rec.approach.astype(float),
                   tau=rec.tau_gravity if tau is None else tau, time=t - t[0],
                   sample=rec.sample, prev_tension=prev_tension, prev_length=prev_length,
                   branch=branch, deadband=np.broadcast_to(deadband, rec.tension.shape))


def collection_order(time: np.ndarray, tension: np.ndarray, length: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per row, the readings logged just before it (in time order; zero before the first
    row: a session starts at home, unloaded, where lengths and tensions are zero), each
    loadcell's hysteresis branch (+1 when its reading rose into the row by more than its
    dead band, −1 when it fell, else the previous row's; the first pose is reached by
    loading), and the (M,) dead bands (``dead_bands``) — what the sensor nuisances
    (``model.sensor_units``) need."""
    order = np.argsort(time, kind="stable")
    y, ln = tension[order], length[order]
    prev_y = np.vstack([np.zeros((1, y.shape[1])), y[:-1]])
    prev_l = np.vstack([np.zeros((1, ln.shape[1])), ln[:-1]])
    change = y - prev_y
    deadband = dead_bands(change[1:])
    branch = np.ones_like(y)
    current = np.ones(y.shape[1])
    for i in range(len(y)):
        current = np.where(np.abs(change[i]) > deadband, np.sign(change[i]), current)
        branch[i] = current
    back = np.empty_like(order)
    back[order] = np.arange(len(order))
    return prev_y[back], prev_l[back], branch[back], deadband


def dead_bands(change: np.ndarray) -> np.ndarray:
    """(M,) change of each loadcell's reading, in N, within which its branch is kept.

    ``BRANCH_DEADBAND``, widened to ``BRANCH_NOISE`` σ of the loadcell's own changes where
    those mostly stay within it (a robust σ below ``BRANCH_DEADBAND``): a wire slack
    through a session never moves its tension, so its changes are its noise. With a 0.3 N
    loadcell, one change in a hundred passes 1 N; the guess then flipped, and stayed flipped
    until noise flipped it back, so half of a slack wire's rows could sit on the wrong
    branch. Its constant length cannot say which, and the fitted hysteresis shrank to fit
    both (docs/diagnosis-notebook.md). A loadcell whose tension moves keeps the plain dead
    band: its changes are moves, not noise."""
    if len(change) < 2:
        return np.full(change.shape[1], BRANCH_DEADBAND)
    sigma = 1.4826 * np.median(np.abs(change - np.median(change, axis=0)), axis=0)
    return np.where(sigma < BRANCH_DEADBAND, BRANCH_DEADBAND + BRANCH_NOISE * sigma,
                    BRANCH_DEADBAND)


def moved_less(data: Samples, h: float) -> np.ndarray:
    """(B, M) entries whose reading changed by less than 2h past its dead band: the change
    may come from a flip of the branch or from none. The dead bands come with the branches
    (``collection_order``)."""
    return np.abs(data.tension - data.prev_tension) < 2.0 * h + data.deadband


def too_few_samples(path: object, n: int) -> DiagnosisInputError:
    """The one message for a recording too short to diagnose."""
    return DiagnosisInputError(
        f"{path}: {n} samples are too few to tell physics from noise; the diagnosis needs at "
        f"least {MIN_SAMPLES} paired samples (ideally 200+): collect or simulate more")


@dataclass
class Paired:
    real: Samples
    reference: Samples | None
    joints: list[str]
    muscles: list[str]
    temp_zero: np.ndarray | None = None  # (M,) °C where each loadcell was zeroed
    temp_zero_source: str = ""


ZERO_TEMPERATURE_KEY = "loadcell_zero_temperature_C"
FIRST_ROWS = 1  # session start: loadcells are zeroed just before the first pose; later rows
# have warmed up already


def zero_temperature(rec: Recording) -> tuple[np.ndarray, str]:
    """Temperature at which each loadcell reads right (its zeroing), and where it came from.

    A loadcell zeroed at the start of a session has no drift error at that temperature.
    The recording may say it (metadata ``loadcell_zero_temperature_C``: one number or one
    per muscle); otherwise the first row, taken right after zeroing, stands in.
    """
    m = len(rec.muscles)
    value = rec.meta.get(ZERO_TEMPERATURE_KEY)
    if value is not None:
        try:
            arr = np.asarray(value, dtype=float)
            arr = np.broadcast_to(arr, (m,)).copy() if arr.ndim == 0 or arr.shape == (m,) \
                else None
        except (TypeError, ValueError):
            arr = None
        if arr is None or not np.all(np.isfinite(arr)):
            raise DiagnosisInputError(
                f"{rec.path}: metadata {ZERO_TEMPERATURE_KEY} must be one number or {m} "
                f"(one per muscle), not {value!r}")
        return arr, "metadata"
    order = np.argsort(rec.time, kind="stable")[:FIRST_ROWS]
    return rec.temperature[order].mean(axis=0), "first sample"


def pair(real: Recording, reference: Recording | None, arm=None,
         min_rows: int = MIN_SAMPLES) -> Paired:
    """Check the recordings describe the same arm and poses; fill missing gravity.

    ``min_rows``: the paired rows this recording must give. A recording diagnosed with
    others (the poses collected to settle a first session, of which the arm may have
    given a few up) needs only to pair; the rows of all of them together must be enough
    (``diagnose``)."""
    if reference is not None:
        for key in ("joints", "muscles"):
            if getattr(real, key) != getattr(reference, key):
                raise DiagnosisInputError(
                    f"{real.path} and {reference.path} describe different arms: {key} "
                    f"{getattr(real, key)} vs {getattr(reference, key)}")
        common, ia, ib = np.intersect1d(real.sample, reference.sample, return_indices=True)
        if len(common) < min_rows:
            for rec in (real, reference):
                if len(rec.sample) < min_rows:
                    raise too_few_samples(rec.path, len(rec.sample))
            raise DiagnosisInputError(
                f"{real.path} and {reference.path} share only {len(common)} sample ids; they "
                "must be recordings of the same commanded poses (same seed)")
        cmd_a, cmd_b = real.theta_command[ia], reference.theta_command[ib]
        bad = np.flatnonzero(np.abs(cmd_a - cmd_b).max(axis=1) > 1e-6)
        if bad.size:
            raise DiagnosisInputError(
                f"{real.path} and {reference.path} do not pair: theta_command differs at "
                f"sample {int(common[bad[0]])}; pass the reference made with the same seed")
    real_tau = real.tau_gravity
    missing = np.isnan(real_tau).any(axis=1)
    if missing.any():
        real_tau = real_tau.copy()
        if arm is not None:
            real_tau[missing] = arm.gravity_torque(real.theta[missing])
        elif reference is not None:
            # same commanded pose: the simulator's gravity torque stands in
            ref_tau = np.full_like(real_tau, np.nan)
            ref_tau[ia] = reference.tau_gravity[ib]
            real_tau[missing] = ref_tau[missing]
        if np.isnan(real_tau).any():
            raise DiagnosisInputError(
                f"{real.path}: {int(np.isnan(real_tau).any(axis=1).sum())} rows have no "
                "tau_gravity; pass --robot so the gravity torque can be computed from the "
                "description")
    real_s = samples_from(real, real_tau)
    ref_s = None
    if reference is not None:
        real_s = real_s.rows(ia)
        ref_tau = reference.tau_gravity[ib]
        gaps = np.isnan(ref_tau).any(axis=1)
        ref_tau[gaps] = real_tau[ia][gaps]  # same commanded pose: the real row's gravity
        if np.isnan(ref_tau).any():
            raise DiagnosisInputError(f"{reference.path} and {real.path} both lack "
                                      "tau_gravity; pass --robot to compute it")
        ref_s = samples_from(reference).rows(ib)
        ref_s.tau = ref_tau
    temp_zero, source = zero_temperature(real)
    return Paired(real_s, ref_s, real.joints, real.muscles, temp_zero, source)


def length_weights(physics: Physics, data: Samples) -> tuple[np.ndarray, dict]:
    """Per-sample weights of the length law, from the noise each length carries.

    The stretch ``log1p(f)/K`` that the schema subtracts inherits the loadcell noise times
    ``1/(K(1+f))``: near slack that is a thousand times an encoder count. Loadcell and
    encoder noise are estimated from an unweighted first fit (torque residuals over the
    muscle Jacobian; length residuals of the well-tensioned half).
    """
    data.len_weight = None
    fit = fit_effects(physics, data, sensor_units(data))
    r_len, r_tau = evaluate(physics, fit, data)
    jac = schema_jacobian(physics, data.theta, fit.weights)
    g2 = np.mean(np.sum(jac**2, axis=1), axis=0)  # (N,) mean Σ_j G_jk²
    sigma_f = float(np.clip(np.median(np.sqrt(np.mean(r_tau**2, 0) / np.maximum(g2, 1e-12))),
                            0.02, 50.0))
    tense = data.tension > np.median(data.tension)
    sigma_l = float(max(np.median([np.sqrt(np.mean(r_len[tense[:, j], j] ** 2))
                                   for j in range(r_len.shape[1]) if tense[:, j].any()]), 1e-7))
    return (stretch_weights(physics.kappa, data.tension, sigma_f, sigma_l),
            {"tension_N": sigma_f, "length_m": sigma_l})


def stretch_weights(kappa: np.ndarray, tension: np.ndarray, sigma_f: float, sigma_l: float
                    ) -> np.ndarray:
    """(B, M) weight of each length: encoder noise against the loadcell noise its stretch
    inherits, ``|κ|·σ_f/(1 + f)``."""
    ratio = np.abs(kappa) * sigma_f / ((1.0 + np.maximum(tension, 0.0)) * sigma_l)
    return 1.0 / np.sqrt(1.0 + ratio**2)


BRANCH_ROUNDS = 3  # refits of the sensors with the branches the lengths tell
BRANCH_FIT = 2.5  # a branch's length within this many of the fit's σ, or the guess stays


def tell_branches(physics: Physics, data: Samples) -> tuple[float, float]:
    """Read from the lengths the loadcell branches that the readings' changes cannot tell;
    returns the hysteresis h they were read with and the share of entries the changes
    could not tell.

    A branch is read from the change of the reading into the row. That change is the
    tension's change plus, where the branch flipped, a jump of 2h against it: a change
    smaller than 2h past the dead band (``dead_bands``) may come from a flip or from none. In a
    narrow session at the floors about half the entries are such, and a quarter to a
    third of their guesses are wrong (the simulator's true branches known;
    docs/diagnosis-notebook.md); a wrong one leaves 2h that follows the direction the
    wire last moved, which an offset, a stiffness change or too small a hysteresis then
    fits. The length says which: the muscle's stretch follows its true tension, so the
    two branches' tensions ``y ± h`` predict lengths that differ by about
    ``2h·|κ|/(1 + f)``, hundreds of micrometres at a floor against an encoder's few (there
    under 1 % stay wrong). It is read with the physics every later fit uses (the chosen
    schema degree): on MuJoCo arms a lower degree's schema error was read as branches.
    Each doubtful entry takes the branch whose length fits the sensors' fit better
    (``_branch_misfits``: measured from its muscle's length constant chosen with the
    branches), if that one fits within ``BRANCH_FIT`` of the fit's noise (where the stretch
    law does not hold as modelled the guess stays), and the sensors are refitted with them
    (``BRANCH_ROUNDS``) — unless the torques, whose balance needs no stretch law, fit worse
    with them: then the lengths are not trusted to tell, and the guesses stay. Nor are they
    asked where the sensors' fit has the loadcells reading higher while loading
    (``hysteresis_reversed``)."""
    if data.branch is None or data.prev_tension is None:
        return 0.0, 0.0
    units = sensor_units(data)
    fit = fit_effects(physics, data, units)
    doubt = np.zeros(data.tension.shape, bool)
    for _ in range(BRANCH_ROUNDS):
        if hysteresis_reversed(fit, UNIT_Z):  # the lengths would tell the wrong way round
            break
        doubt = moved_less(data, hysteresis(fit))
        if not doubt.any():
            break
        sq = _branch_misfits(physics, fit, data, doubt)
        # the better branch's length within the fit's noise: else the stretch law does not
        # hold there as modelled, and the length tells nothing
        clear = doubt & (np.minimum(sq[0], sq[1]) <= BRANCH_FIT**2)
        told = np.where(clear, np.where(sq[0] <= sq[1], 1.0, -1.0), data.branch)
        if np.array_equal(told, data.branch):
            break
        new = fit_effects(physics, replace(data, branch=told), units)
        # the torques need no stretch law: branches that fit them worse are not told
        if np.sum(np.log(new.sigma_tau)) > np.sum(np.log(fit.sigma_tau)):
            break
        data.branch, fit = told, new
    return hysteresis(fit), float(np.mean(doubt))


def _branch_misfits(physics: Physics, fit: Fit, data: Samples, doubt: np.ndarray
                    ) -> list[np.ndarray]:
    """(B, M) squared length misfit, in the fit's σ, of each doubtful entry on the loading
    (+1) and the unloading (−1) branch, the rest on their own.

    Each is measured from its muscle's length constant in its session chosen again with the
    branches: the fit's constant was fitted with the guesses, and where most of a muscle's
    rows sit on a wrong branch (one flip missed early, its guess carried on) it lies
    between the two, and each wrong row fits its wrong branch better. So the constant is
    the one that lets the most lengths fit one of their branches (each row's misfit capped
    at ``BRANCH_FIT``), scanned over the values the rows propose; a flip of a whole
    session cannot be told this way and is not (the constant takes it)."""
    plain = replace(data, len_weight=None)  # in metres, shifted by one constant per session
    e = [evaluate(physics, fit, replace(plain, branch=np.where(doubt, b, data.branch)))[0]
         for b in (1.0, -1.0)]
    weight = (np.ones_like(e[0]) if data.len_weight is None else data.len_weight
              ) / fit.sigma_len
    sessions = np.zeros(data.n, int) if data.session is None else data.session
    shift = np.zeros_like(e[0])
    for s in np.unique(sessions):
        rows = sessions == s
        for j in range(e[0].shape[1]):
            if not doubt[rows, j].any():
                continue
            # (2, R): a told entry's two rows are equal (its own branch in both)
            ej = np.stack([e[0][rows, j], e[1][rows, j]])
            candidates = np.unique(np.concatenate([[0.0], ej.ravel()]))
            z = (ej[:, :, None] - candidates) * weight[rows, j][None, :, None]
            cost = np.minimum(np.min(z**2, axis=0), BRANCH_FIT**2).sum(axis=0)
            best = np.argmin(cost)
            if cost[best] < cost[candidates == 0.0][0]:  # ties keep the fit's constant
                shift[rows, j] = candidates[best]
    return [((x - shift) * weight) ** 2 for x in e]


def tell_all(physics: Physics, real: Samples, ref: Samples | None, info: dict) -> None:
    """``tell_branches`` on the real recording and its reference."""
    for data in (real, ref):
        if data is not None:
            h, share = tell_branches(physics, data)
            if data is real and share:
                info["loadcell_branches_from_lengths"] = {"doubtful_share": share,
                                                          "hysteresis_N": h}


def degrees_for(n_joints: int, n_rows: int) -> list[int]:
    options = {1: [3, 4, 5, 6, 7], 2: [3, 4, 5, 6], 3: [3, 4, 5], 4: [3, 4, 5], 5: [3, 4]}.get(
        n_joints, [2, 3])
    fits = [d for d in options
            if PolyBasis(n_joints, d, np.zeros(n_joints), np.ones(n_joints)).size < 0.3 * n_rows]
    return fits or [2]


def build_physics(paired: Paired, kappa: np.ndarray | None, arm=None
                  ) -> tuple[Physics, dict]:
    """Gravity function, elasticity and schema basis for the real recording; with the robot
    description ``arm``, each link's own gravity too (a link mass is then one link's), and
    its routing as the schema: as it is, or corrected where a correction predicts held-out
    rows clearly better (``fit.choose_schema``)."""
    real, ref = paired.real, paired.reference
    theta_all = real.theta if ref is None else np.vstack([real.theta, ref.theta])
    tau_all = real.tau if ref is None else np.vstack([real.tau, ref.tau])
    ok = ~np.isnan(tau_all).any(axis=1)
    gravity = GravityFunction(theta_all[ok], tau_all[ok])
    info: dict = {"gravity_fit_rel_error": gravity.rms_error / max(gravity.rms_tau, 1e-12)}
    links, link_gravity, routings = (), None, [None]
    if arm is not None:
        from pimbs_learn.diagnosis.robot_file import FileRouting, link_torques

        names, torques = link_torques(arm, theta_all)
        if names:
            links = tuple(names)
            link_gravity = np.stack([gravity.project(theta_all, t) for t in torques])
        routings = [FileRouting(arm), None]
    lo, hi = real.theta.min(0), real.theta.max(0)
    center, scale = (lo + hi) / 2, np.maximum((hi - lo) / 2, 1e-3)
    m = real.tension.shape[1]
    temp_zero = (real.temperature[:FIRST_ROWS].mean(0) if paired.temp_zero is None
                 else paired.temp_zero)
    info["loadcell_zero_temperature_C"] = temp_zero.tolist()
    info["loadcell_zero_temperature_source"] = paired.temp_zero_source or "first samples"

    recordings = 1 if real.session is None else len(np.unique(real.session))

    def make(schema: tuple, kap: np.ndarray, count: int = recordings) -> Physics:
        degree, routing = schema
        return Physics(PolyBasis(real.theta.shape[1], degree, center, scale), kap, gravity,
                       temp_zero, recordings=count, links=links, link_gravity=link_gravity,
                       routing=routing)

    start = np.full(m, DEFAULT_KAPPA) if kappa is None else np.asarray(kappa, float)
    degrees = degrees_for(real.theta.shape[1], real.n)
    # the noise levels are estimated with each recording's own length constant, as every
    # fit holds them: one constant over sessions homed apart reads their shift as noise
    def weigh(physics: Physics) -> None:
        for data in (real, ref):
            if data is not None:
                data.len_weight, noise = length_weights(physics, data)
                if data is real:
                    info["noise_estimate"] = noise

    def weigh_for(schema: tuple | None) -> None:
        """Noise levels under the file's routing where it is the schema (it leaves less to
        length noise), else under a free schema of the middle degree."""
        free = (degrees[len(degrees) // 2], None)
        weigh(make(schema if schema is not None and schema[1] is not None else free, start))

    weigh_for(None)  # before a schema is chosen
    # simplest first: the file's routing as it is (up to each muscle's constant: its
    # motor's homing), then corrected by the degrees the rows allow, the file's routing
    # before none at each degree. Not linearly: a linear correction won held-out rows from
    # the file as it is where MuJoCo's tendons or a narrow session's stretch differ from
    # it, and took too little of the difference in; what it left was named
    # (docs/diagnosis-notebook.md)
    options = sorted([(d, r) for r in routings
                      for d in ([0, *degrees] if r is not None else degrees)],
                     key=lambda o: (o[0], o[1] is None))
    kappa_start = start  # both choices compare the options at this elasticity (``start``
    # takes the reference's correction below)
    schema = choose_schema(lambda o: make(o, kappa_start), real, options)
    if schema[1] is not None:
        weigh_for(schema)
    if kappa is None:
        if ref is None:
            raise DiagnosisInputError("need a reference recording or a robot description to "
                                      "know the modelled elasticity K")
        # The reference obeys the model by construction: its lengths and torque balance
        # reveal the modelled elasticity (and the sign convention of its writer), where
        # each muscle's tension varies apart from its pose.
        units = [Unit("elastic_stiffness", j) for j in range(m)]
        ref_fit = fit_effects(make(schema, start), ref, units)
        start = start * (1.0 + ref_fit.params)
        info["kappa_source"] = "reference"
    else:
        info["kappa_source"] = "description"
    info["kappa"] = start.tolist()
    physics = make(schema, start)
    guesses = [None if d is None else d.branch for d in (real, ref)]
    tell_all(physics, real, ref, info)
    # the schema was chosen on the guessed branches, whose errors at the floors (2h of
    # stretch that follows the path) a free schema can take in and the file's routing
    # cannot: chosen again on the told ones, and the branches told again with it
    told = guesses[0] is not None and not np.array_equal(real.branch, guesses[0])
    again = choose_schema(lambda o: make(o, kappa_start), real, options) if told else schema
    if again != schema:
        schema, physics = again, make(again, start)
        for data, guess in zip((real, ref), guesses, strict=True):
            if data is not None:
                data.branch = guess
        weigh_for(schema)
        tell_all(physics, real, ref, info)
    info["schema_degree"] = schema[0]
    info["schema"] = "learned from the real recording"
    info["schema_from_robot_file"] = physics.routing is not None
    if ref is not None:
        tied = tie_to_reference(physics, real, ref)
        if tied is not None:
            physics = tied
            info["schema"] = "the reference's (the real routing matches it)"
    return physics, info


ROUTING_MATCH = 2.0  # tied length residuals within this factor of free ones: same routing


def tie_to_reference(physics: Physics, real: Samples, ref: Samples) -> Physics | None:
    """The reference's body schema, if the real arm's routing matches it.

    Routing is a nuisance the real data can teach, at a price: a learned schema absorbs any
    pure shift of a joint's zero, which gravity cannot reveal for joints whose rotation
    does not lift the arm (a forearm's roll). When the reference's schema, shifted by the
    best joint offsets, explains every muscle's real lengths about as well as a freely
    learned one (measured: ≤ 1.3× with the same routing, ≥ 2.9× for 2 mm via-point shifts),
    the routing is the same and the tighter, tied model is used.
    """
    ref_state = apply_effects(physics, ref, [], np.zeros(0))
    tied = replace(physics, tied=fit_schema(physics, ref_state, ref), _cache={})
    # Both sides may also rescale the elasticity: a stiffness error must not pass for (or
    # hide) a routing difference.
    elastic = [Unit("elastic_stiffness", j) for j in range(real.tension.shape[1])]
    sensor = sensor_units(real)
    free = fit_effects(physics, real, sensor + elastic, passes=1)
    shifts = [Unit("joint_offset", k) for k in range(real.theta.shape[1])]
    shifted = fit_effects(tied, real, sensor + elastic + shifts, passes=1)
    # every muscle must match: one rerouted muscle forced onto the reference's path would
    # be explained by joint offsets and loadcell errors that are not there
    ratio = np.max(shifted.sigma_len / free.sigma_len)
    return tied if ratio < ROUTING_MATCH else None


def combine(parts: list[Paired]) -> Paired:
    """Several recordings of one arm as one data set (a first recording and the poses
    collected to settle what it could not tell apart).

    Rows are stacked; each keeps the zeroing temperature of its own session (a collection
    zeroes its loadcells at its start), so a thermal drift is anchored per session. The
    physics (gravity function, body schema) is then fitted on all rows together.
    """
    first = parts[0]
    if len(parts) == 1:
        return first
    for p in parts[1:]:
        if p.joints != first.joints or p.muscles != first.muscles:
            raise DiagnosisInputError(
                "the recordings describe different arms: joints/muscles "
                f"{first.joints}/{first.muscles} vs {p.joints}/{p.muscles}; diagnose "
                "recordings of one arm together")
    if len({p.reference is None for p in parts}) > 1:
        raise DiagnosisInputError(
            "give one --reference per recording (`pimbs simulate --poses-file` makes the one "
            "for a poses file), or none and --robot")

    def stack(samples: list[Samples], zero: list[np.ndarray]) -> Samples:
        out = Samples(**{k: np.concatenate([getattr(s, k) for s in samples])
                         for k in ("theta", "tension", "length", "temperature", "approach",
                                   "tau", "time", "sample")})
        for k in ("prev_tension", "prev_length", "branch", "deadband"):  # each its own
            if all(getattr(s, k) is not None for s in samples):
                setattr(out, k, np.concatenate([getattr(s, k) for s in samples]))
        out.temp_zero = np.concatenate([np.broadcast_to(z, s.tension.shape)
                                        for s, z in zip(samples, zero, strict=True)])
        out.session = np.concatenate([np.full(s.n, i) for i, s in enumerate(samples)])
        return out

    zeros = [p.temp_zero for p in parts]
    real = stack([p.real for p in parts], zeros)
    ref = None if first.reference is None else stack([p.reference for p in parts], zeros)
    return Paired(real, ref, first.joints, first.muscles, first.temp_zero,
                  first.temp_zero_source)
