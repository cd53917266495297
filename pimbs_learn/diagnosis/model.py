"""The physics the diagnosis fits: a body schema plus candidate effects, two residual channels.

A static sample obeys two laws, whatever the arm:

* **length** (L): ``l = h(θ_true) + κ ⊙ log1p(f_true)`` — the body schema ``h`` (muscle
  routing, learned from the data themselves as a smooth function, so that a routing that
  differs from the model is never mistaken for an effect; with the robot file, learned as
  the file's routing plus a smooth correction, ``robot_file``) plus the elastic stretch of
  ``f = exp(KΔn) − 1`` (``κ = ∓1/K``, from the robot file, else from the reference);
* **torque** (T): ``−G(θ_true)ᵀ f_true = g_true(θ_true)`` with ``G = ∂h/∂θ`` of that same
  schema.

An effect changes what the sensors report (``f``, ``θ``) or what the model assumes
(``g``, ``K``). Each effect has *units*, one parameter per muscle or joint:

============== ======================================= =====================================
effect         unit parameter                          acts as
============== ======================================= =====================================
tension_offset b_j [N]                                 f_true = f − b_j
tension_gain   g_j [–]                                 f_true = f / (1 + g_j)
thermal_drift  c_j [N/°C]                              f_true = f − c_j (T_j − T0_j)
tendon_friction μ_j [–]                                f_true = f · exp(a_j μ_j) (capstan)
elastic_stiffness s_j [–]                              κ_j → κ_j (1 + s_j)   (K_true = K/(1+s))
joint_offset   δ_k [rad]                               θ_true = θ − δ
link_mass      s_i [–] for link i (robot file given)    g += s_i τ_i   (τ_i: link i's own)
               β_k, γ_ki [–] beyond joint k (no file)   g += β ∇V_distal,k + Σ γ_ki ∇V_i
============== ======================================= =====================================

With the robot file, each link's own gravity torque ``τ_i`` is known
(``robot_file.link_torques``): a link that weighs ``1 + s_i`` times what the file says, at
its centre of mass, adds ``s_i τ_i``. Without it, ``V_distal,k`` is the part of the model's
gravity potential that moves with joints ≥ k: a mass change of the links beyond joint k
scales it exactly (``β = scale − 1``); its share of each proximal level ``V_i`` (terms whose
last joint is i < k) is not identifiable from τ samples and gets its own ``γ_ki``.

A thermal drift is anchored where the loadcell was zeroed (per muscle, or one coefficient
common to all loadcells of one type and amplifier: pooled, it is seen where per-muscle
coefficients are too weak — four loadcell errors against two torque equations on a 2-DOF
arm): it reads right at ``T0_j``, the
temperature at zeroing (a metadata field, or the first samples of the session), so drift
and a constant offset are separate effects that can be present together. A gain error
grows with the tension, an offset does not, and a stiffness error leaves the torque
balance alone: the three are told apart by how the error scales with tension.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from pimbs_learn.diagnosis.bases import GravityFunction, PolyBasis

if TYPE_CHECKING:
    from pimbs_learn.diagnosis.robot_file import FileRouting

EFFECTS = ("tendon_friction", "link_mass", "tension_offset", "tension_gain", "thermal_drift",
           "elastic_stiffness", "joint_offset")


@dataclass(frozen=True)
class Unit:
    """One parameter: ``effect`` on muscle or joint ``index`` (``part`` for 2-param units)."""

    effect: str
    index: int
    part: str = ""

    @property
    def label(self) -> str:
        return f"{self.effect}[{self.index}]{'.' + self.part if self.part else ''}"


def link_place(physics: Physics, unit: Unit, joints: list[str]) -> str:
    """Where a link-mass unit's change sits, in words: the link, or the links beyond a joint."""
    if unit.part == "link":
        return f"link {physics.links[unit.index]}"
    return f"links beyond {joints[unit.index]}"


# Physics outside the vocabulary, fitted only to ask whether it takes a name's place
# (``confound.outside_rival``), never named: a passive spring at one joint — a cover, a
# cable bundle, a joint's stop — whose torque ``rate·θ + torque`` pulls toward the angle
# ``−torque/rate`` (units ``Unit(SPRING, joint, "rate")`` in N·m/rad, restoring when
# positive, and ``Unit(SPRING, joint, "torque")`` in N·m at the description's zero).
SPRING = "joint_spring"

SENSOR = ("sensor_lag", "loadcell_hysteresis")
MAX_LAG = 0.9  # share of the previous reading: beyond it the undone reading is mostly noise


def sensor_units(data: Samples) -> list[Unit]:
    """The sensors' own nuisances, fitted beside every model and never named as effects.

    Every board reads through a filter and every loadcell has hysteresis, on any arm. A
    reading taken soon after the pose is reached keeps a share ``a`` of the previous one
    (``y_i = x_i + a·(y_{i−1} − x_i)``, loadcells and motor encoders alike); a loadcell reads
    lower on its loading branch than on its unloading one (``f ∓ h``). Neither is an error
    of the arm's model, yet left out they are mistaken for one: on a population of drawn
    arms a leak of 3 % of the previous reading and 0.7 N of hysteresis made a clean
    recording name a link mass, capstan friction and a stiffness change
    (docs/diagnosis-notebook.md). One leak ``a`` for all readings and one hysteresis ``h``
    for all loadcells, when the rows' collection order is known.
    """
    if data.prev_tension is None:
        return []
    return [Unit("sensor_lag", -1, "common"), Unit("loadcell_hysteresis", -1, "common")]


def units_of(effect: str, physics: Physics, data: Samples) -> list[list[Unit]]:
    """Groups of units that are selected together (one group per muscle, joint, link of
    the robot file (``physics.links``), or, without the file, subtree)."""
    n_joints, n_muscles, links = data.theta.shape[1], data.tension.shape[1], len(physics.links)
    if effect == "thermal_drift":  # per muscle, or one coefficient shared by all loadcells
        return [[Unit(effect, j)] for j in range(n_muscles)] + (
            [[Unit(effect, -1, "common")]] if n_muscles > 1 else [])
    if effect in ("tension_offset", "tension_gain", "tendon_friction", "elastic_stiffness"):
        return [[Unit(effect, j)] for j in range(n_muscles)]
    if effect == "joint_offset":
        return [[Unit(effect, k)] for k in range(n_joints)]
    if effect == "link_mass" and links:
        return [[Unit(effect, i, "link")] for i in range(links)]
    if effect == "link_mass":
        return [[Unit(effect, 0, "distal")]] + [
            [Unit(effect, k, "distal")] + [Unit(effect, k, f"level{i}") for i in range(k)]
            for k in range(1, n_joints)]
    raise ValueError(f"unknown effect {effect!r}")


@dataclass
class Samples:
    """The arrays of one recording (or a subset of its rows) that the physics uses."""

    theta: np.ndarray        # (B, N) rad
    tension: np.ndarray      # (B, M) N
    length: np.ndarray       # (B, M) m
    temperature: np.ndarray  # (B, M) °C
    approach: np.ndarray     # (B, M) −1/0/+1
    tau: np.ndarray          # (B, N) N·m, model gravity torque at θ
    time: np.ndarray         # (B,) s since the first sample
    sample: np.ndarray       # (B,) sample ids
    # (B, M) weight of each length in the fit: a slack muscle's stretch log1p(f)/K is
    # dominated by loadcell noise (d/df = 1/(K(1+f))), so its length says little.
    len_weight: np.ndarray | None = None
    # (B, M) °C at which each row's loadcells were zeroed, when the rows come from several
    # recordings (each zeroes its loadcells at its start); None: ``Physics.temp_zero``
    temp_zero: np.ndarray | None = None
    session: np.ndarray | None = None  # (B,) which recording each row came from
    # (B, M) the readings logged just before each row in collection order (zero before a
    # session's first row: the arm at home, unloaded, where lengths and tensions are zero),
    # and each loadcell's branch (+1: its tension rose into this pose, −1: fell); None:
    # unknown, and the sensor nuisances (``SENSOR``) then do nothing
    prev_tension: np.ndarray | None = None
    prev_length: np.ndarray | None = None
    branch: np.ndarray | None = None
    # (B, M) N: a reading's change within this may be the loadcell's noise and dead band,
    # not a move of its tension (``inputs.collection_order``)
    deadband: np.ndarray | None = None

    def rows(self, idx: np.ndarray) -> Samples:
        return Samples(**{k: None if v is None else v[idx] for k, v in self.__dict__.items()})

    @property
    def n(self) -> int:
        return len(self.theta)


@dataclass
class Physics:
    """What is fixed while effects are fitted: schema basis, elasticity, gravity function."""

    basis: PolyBasis
    kappa: np.ndarray            # (M,) elastic coefficient of log1p(f) in the length law
    gravity: GravityFunction
    temp_zero: np.ndarray        # (M,) °C at which each loadcell reads right (T0)
    ridge: float = 1e-9
    # schema of the reference (as ``fit_schema`` returns it), when the real arm's routing
    # matches it: then only a constant per muscle (and recording) is refitted, and a joint
    # offset shows in the lengths too.
    tied: np.ndarray | None = None
    # recordings whose rows are fitted together: one body schema, and each recording after
    # the first a length constant of its own per muscle (``blocks``)
    recordings: int = 1
    # the links a mass change can sit on (from the robot file) and, (L, P), each one's own
    # gravity in the basis of ``gravity``; empty without the file
    links: tuple[str, ...] = ()
    link_gravity: np.ndarray | None = None
    # the robot file's routing (``robot_file.FileRouting``): the schema is then its lengths
    # plus the basis' correction; None: the basis alone
    routing: FileRouting | None = None
    _cache: dict = field(default_factory=dict, repr=False)

    def blocks(self, values: np.ndarray, session: np.ndarray | None) -> np.ndarray:
        """(B, P) basis values → (B, P + R − 1): the shared basis, then the constant
        monomial of each recording after the first, on its rows only.

        Each session on the arm starts from its own homing of the motors, so a muscle's
        length is known up to a constant per session; the routing (the rest of the
        schema) is one body's and is fitted on every row. Rows of no recorded session
        (poses proposed for the next one) take the latest recording's constant. The
        constants have no gradient: the Jacobian is the shared schema's
        (``weights[:basis.size]``)."""
        if self.recordings == 1:
            return values
        s = np.full(len(values), self.recordings - 1) if session is None else session
        extra = [values[:, :1] * (s == k)[:, None] for k in range(1, self.recordings)]
        return np.concatenate([values, *extra], axis=1)

    def constant(self, session: int) -> int:
        """Index of the schema coefficient that shifts ``session``'s lengths alone (the
        first recording's is the shared constant, monomial 0)."""
        return 0 if session == 0 else self.basis.size + session - 1

    def basis_at(self, theta: np.ndarray, key, weight: np.ndarray | None = None,
                 session: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, list]:
        """Basis values (B, P + R − 1) (``blocks``; ``session``: each row's recording),
        gradients as (B, N, P), and per-muscle factorisations of the weighted normal
        equations — memoised per ``key``: the effect fits revisit the same poses and weights
        many times."""
        if key is not None and key in self._cache:
            return self._cache[key]
        values = self.blocks(self.basis.values(theta), session)
        grads = np.ascontiguousarray(self.basis.gradients(theta).transpose(0, 2, 1))
        eye = np.eye(values.shape[1])
        factors = []
        for w in (np.ones((len(values), 1)) if weight is None else weight).T:
            ata = (values * (w**2)[:, None]).T @ values
            factors.append(cho_factor(ata + self.ridge * np.trace(ata) / len(ata) * eye))
        out = (values, grads, factors)
        if key is not None:
            if len(self._cache) > 64:
                self._cache.clear()
            self._cache[key] = out
        return out


@dataclass
class State:
    """Corrected quantities of a set of samples under given effect parameters."""

    theta: np.ndarray
    tension: np.ndarray
    kappa: np.ndarray
    tau: np.ndarray
    # (B, M) factor by which undoing the readings scaled their noise (a gain, capstan
    # friction, the sensor's lag), or None (see ``residuals``)
    scale: np.ndarray | None = None
    length: np.ndarray | None = None  # (B, M) motor lengths with the sensor's lag undone
    len_scale: float = 1.0            # ... and the factor that scaled their noise


def apply_effects(physics: Physics, data: Samples, units: list[Unit],
                  params: np.ndarray) -> State:
    """Undo the effects: the true pose, tensions, elasticity and gravity they imply."""
    theta = data.theta
    f, length, noise, len_noise = _undo_sensor(data, units, params)
    kappa = physics.kappa.copy()
    delta = np.zeros(theta.shape[1])
    gravity_extra = np.zeros(physics.gravity.coef.shape)
    gain = np.zeros(f.shape[1])
    scale = np.ones(f.shape[1])
    rate, torque = np.zeros(theta.shape[1]), np.zeros(theta.shape[1])  # ``SPRING``
    for u, p in zip(units, params, strict=True):
        if u.effect in SENSOR:
            continue
        if u.effect == "tension_offset":
            f[:, u.index] -= p
        elif u.effect == "thermal_drift":
            j = slice(None) if u.part == "common" else u.index
            t0 = physics.temp_zero[None, :] if data.temp_zero is None else data.temp_zero
            f[:, j] -= p * (data.temperature[:, j] - t0[:, j])
        elif u.effect == "tension_gain":  # a factor 1 + g ≤ 0 reads no tension at all
            scale[u.index] = 1.0 / (1.0 + p) if p > -1.0 else np.nan
        elif u.effect == "tendon_friction":
            gain[u.index] = p
        elif u.effect == "elastic_stiffness":
            kappa[u.index] *= 1.0 + p
        elif u.effect == "joint_offset":
            delta[u.index] = p
        elif u.effect == SPRING:
            (rate if u.part == "rate" else torque)[u.index] = p
        elif u.effect == "link_mass":
            if u.part == "link":
                gravity_extra += p * physics.link_gravity[u.index]
            elif u.part == "distal":
                gravity_extra += p * physics.gravity.distal_split(u.index)[0]
            else:
                gravity_extra += p * physics.gravity.level(int(u.part.removeprefix("level")))
    # the loadcell's chain, undone from the reading back: bias and drift, gain, friction
    factor = None
    if np.any(scale != 1.0):
        factor = np.broadcast_to(scale, f.shape)
    if np.any(gain):
        factor = (1.0 if factor is None else factor) * np.exp(data.approach * gain)
    if factor is not None:
        f *= factor
    if noise != 1.0:
        factor = noise * (np.ones(f.shape) if factor is None else factor)
    tau = data.tau
    if np.any(delta):
        theta = theta - delta
        tau = tau + physics.gravity.torque(theta) - physics.gravity.torque(data.theta)
    if np.any(gravity_extra):
        tau = tau + physics.gravity.torque(theta, gravity_extra)
    if np.any(rate) or np.any(torque):  # the muscles also hold the spring's pull
        tau = tau + rate * theta + torque
    return State(theta, f, kappa, tau, factor, length, len_noise)


def _undo_sensor(data: Samples, units: list[Unit], params: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(tensions, lengths) as the sensors' filters and the loadcells' hysteresis had them
    before reading, and the factor by which that scaled the readings' noise (tensions,
    lengths). The chain is undone from the reading back: the filter first, then the branch."""
    f = data.tension.astype(float, copy=True)
    length = data.length
    lag = hyst = 0.0
    for u, p in zip(units, params, strict=True):
        if u.effect == "sensor_lag" and data.prev_tension is not None:
            lag = float(np.clip(p, -MAX_LAG, MAX_LAG))
        elif u.effect == "loadcell_hysteresis" and data.branch is not None:
            hyst = float(p)
    noise = 1.0
    if lag:
        # x = (y − a·y_prev)/(1 − a): white reading noise comes out √(1 + a²)/(1 − a) as large
        f = (f - lag * data.prev_tension) / (1.0 - lag)
        length = (length - lag * data.prev_length) / (1.0 - lag)
        noise = float(np.sqrt(1.0 + lag**2) / (1.0 - lag))
    if hyst:
        f = f + hyst * data.branch  # the loading branch (+1) reads low
    return f, length, noise, noise


def stretch_term(tension: np.ndarray) -> np.ndarray:
    """log1p(f), continued linearly below 0 (C¹ at 0).

    A slack muscle's loadcell reads noise around zero; clipping it at zero would bias the
    stretch upwards and make a tension offset look like it explains slack muscles.
    """
    return np.where(tension >= 0, np.log1p(np.maximum(tension, 0.0)), tension)


def schema_target(physics: Physics, state: State, data: Samples) -> np.ndarray:
    """Length minus the elastic stretch (and minus the file's routing, when the schema is
    anchored to it): what the body schema's basis must explain."""
    length = data.length if state.length is None else state.length
    out = length - state.kappa * stretch_term(state.tension)
    if physics.routing is not None:
        out = out - physics.routing.at(state.theta)[0]
    return out


def fit_schema(physics: Physics, state: State, data: Samples, key=None) -> np.ndarray:
    """Least-squares body schema weights on these samples: (P, M), or (P + R − 1, M) for R
    recordings fitted together (``Physics.blocks``)."""
    values, _, factors = physics.basis_at(state.theta, key, data.len_weight, data.session)
    y = schema_target(physics, state, data)
    if physics.tied is not None:  # refit only the constants (monomial 0 of each recording)
        w2 = np.ones_like(y) if data.len_weight is None else data.len_weight**2
        weights = physics.tied.copy()
        session = (np.zeros(len(y), int) if data.session is None or physics.recordings == 1
                   else data.session)
        for s in np.unique(session):  # in order: the first's constant shifts every row
            rows = session == s
            rest = w2[rows] * (y[rows] - values[rows] @ weights)
            weights[physics.constant(s)] += (np.sum(rest, 0)
                                             / np.maximum(np.sum(w2[rows], 0), 1e-300))
        return weights
    if len(factors) == 1:
        return cho_solve(factors[0], values.T @ y)
    w2 = data.len_weight**2
    return np.stack([cho_solve(f, values.T @ (w2[:, j] * y[:, j]))
                     for j, f in enumerate(factors)], axis=1)


def schema_jacobian(physics: Physics, theta: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """G = ∂h/∂θ of the fitted schema, as (B, M, N) (no normal equations needed)."""
    jac = np.einsum("bpn,pm->bmn", physics.basis.gradients(theta), weights[:physics.basis.size])
    return jac if physics.routing is None else jac + physics.routing.at(theta)[1]


def residuals(physics: Physics, state: State, data: Samples, weights: np.ndarray,
              key=None) -> tuple[np.ndarray, np.ndarray]:
    """(length residual (B, M) in m, torque residual (B, N) in N·m)."""
    values, grads, _ = physics.basis_at(state.theta, key, data.len_weight, data.session)
    r_len = schema_target(physics, state, data) - values @ weights
    if data.len_weight is not None:
        r_len = r_len * data.len_weight
    if state.len_scale != 1.0:  # in reading units, like the torques (``reading_scale``)
        r_len = r_len / state.len_scale
    gt = grads @ weights[:physics.basis.size]  # Gᵀ per sample, (B, N, M)
    if physics.routing is not None:
        gt = gt + physics.routing.at(state.theta)[1].transpose(0, 2, 1)
    r_tau = -(gt @ state.tension[:, :, None])[:, :, 0] - state.tau
    if state.scale is not None:
        r_tau = r_tau / reading_scale(gt, state.scale)
    return r_len, r_tau


def reading_scale(gt: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(B, N) factor by which scaled readings scale each joint's torque noise.

    The loadcell noise is in the readings; undoing a gain ``f/(1 + g)`` shrinks it with
    the tension, and a likelihood with each joint's noise level profiled out would reward
    that shrinkage for itself: all gains up and all gravity down fits "better" without
    limit. So the torque residual is expressed in reading units (the noise of joint ``i``
    at a sample is Σ_j G_ij² s_j² σ² against Σ_j G_ij² σ² without the scale) — then a
    gain common to all loadcells is exactly a common scale of the gravity torques, as the
    physics says, and not a likelihood bonus of n·N·log(1 + g).
    """
    g2 = gt**2
    return np.sqrt(np.einsum("bnm,bm->bn", g2, scale**2)
                   / np.maximum(g2.sum(axis=2), 1e-300))


@dataclass
class Fit:
    """Effect parameters fitted on a training set, with what is needed to predict."""

    units: list[Unit]
    params: np.ndarray
    weights: np.ndarray
    sigma_len: np.ndarray
    sigma_tau: np.ndarray
    log_lik: float
    cov: np.ndarray | None = None

    def with_params(self, params: np.ndarray) -> Fit:
        return replace(self, params=params)


def _hysteresis_index(fit: Fit) -> int | None:
    """Where the loadcells' hysteresis sits among the fit's parameters (None: not fitted)."""
    return next((i for i, u in enumerate(fit.units) if u.effect == "loadcell_hysteresis"),
                None)


def hysteresis(fit: Fit) -> float:
    """The loadcells' fitted hysteresis h, N (0 where the fit has none)."""
    i = _hysteresis_index(fit)
    return 0.0 if i is None else abs(float(fit.params[i]))


def _se(fit: Fit, i: int) -> float:
    """The standard error of the fit's parameter ``i`` (``fit.cov`` given)."""
    return float(np.sqrt(max(float(fit.cov[i, i]), 0.0)))


def hysteresis_reversed(fit: Fit, z: float) -> bool:
    """Whether the fit puts the loadcells' hysteresis below zero by more than ``z`` standard
    errors: loadcells that read higher while their tension rises, which none does.

    Something else in the recording has then taken the hysteresis's place: in a narrow
    session a stiffness change moves each length with its wire's tension, and so with the
    direction the wire last moved, as a hysteresis of the other sign would
    (docs/diagnosis-notebook.md). Branches read from the lengths with that sign come out the
    wrong way round."""
    i = _hysteresis_index(fit)
    if i is None or fit.cov is None:
        return False
    return bool(fit.params[i] < -z * _se(fit, i))


# effects whose parameter p scales a physical quantity by 1 + p: a loadcell's gain, a
# wire's elasticity. No loadcell reads tension with a factor of zero or less, and no wire
# stretches nothing or shortens as it is pulled.
FACTORS = ("tension_gain", "elastic_stiffness")


def factors_not_positive(fit: Fit, units: list[Unit], z: float) -> list[Unit]:
    """Units of ``units`` whose factor ``1 + p`` the fit does not hold above zero by ``z``
    standard errors: amounts no arm has.

    In a narrow session a wire's stretch follows its pose nearly as closely as the body
    schema does, and a stiffness "change" fitted to 1 + s between −0.1 and 0.2 (the
    elasticity scaled to nothing) explained, on arms with nothing of the kind, what the
    schema, a thermal drift or guessed loadcell branches had left in the lengths
    (docs/diagnosis-notebook.md). Such a fit says where the mismatch is, not what it is."""
    if fit.cov is None:
        return []
    index = {u: fit.units.index(u) for u in units if u.effect in FACTORS}
    return [u for u, i in index.items() if 1.0 + fit.params[i] < z * _se(fit, i)]


def evaluate(physics: Physics, fit: Fit, data: Samples, key=None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Residuals of ``data`` under a fit (its effect parameters and body schema)."""
    state = apply_effects(physics, data, fit.units, fit.params)
    return residuals(physics, state, data, fit.weights,
                     key if not _moves_pose(fit.units) else None)


def _moves_pose(units: list[Unit]) -> bool:
    return any(u.effect == "joint_offset" for u in units)


def profile_log_lik(r_len: np.ndarray, r_tau: np.ndarray) -> float:
    """Gaussian log-likelihood with each muscle's and joint's variance profiled out."""
    n = len(r_len)
    rss = np.concatenate([np.sum(r_len**2, 0), np.sum(r_tau**2, 0)])
    return float(-0.5 * n * np.sum(np.log(np.maximum(rss / n, 1e-300))))
