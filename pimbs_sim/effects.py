"""Physics that a real arm has and the static model leaves out.

Used to make "real" data in which an effect is present but labelled nowhere: by
``pimbs simulate --conceal`` and by the simulated boards of the mock bus. Each effect acts
at the place it acts on a real robot:

* on the **physics** of the arm (``link_mass``, ``elastic_stiffness``, ``routing``,
  ``joint_spring``): the true arm differs from the model in mass, stiffness or tendon path,
  or a passive spring (a cover, cables, a joint's stop) pulls a joint toward one angle;
* on the **pose** (``joint_offset``): the joint encoder's zero is off, so the controller
  puts the arm at ``θ_cmd − δ`` while the encoder reports ``θ_cmd``;
* on the **tension reading** (``tendon_friction``, ``tension_gain``, ``tension_offset``,
  ``thermal_drift``): the loadcell sits at the motor, so it reads the joint-side tension
  through capstan friction ``f·exp(−a·μ)`` (``a`` the approach direction, +1 lengthening),
  with a calibration gain error ``(1 + g)·f``, a bias, or a drift proportional to
  ``T − T_ref`` (zero at the temperature where the loadcell was zeroed).

Specs are text, ``NAME[:PARAMS]``: ``tendon_friction:0.2``,
``tension_offset:15,muscles=m1``, ``tension_gain:0.15,muscles=m2`` (reads 15 % high),
``link_mass:1.4,link=forearm`` (mass scale),
``joint_offset:0.05,joints=elbow_pitch``, ``thermal_drift:0.8`` (N/°C),
``elastic_stiffness:0.6`` (K scale), ``joint_spring:1.5,joints=elbow,rest=0.2`` (N·m/rad,
pulling toward 0.2 rad; outside what the diagnosis names), ``routing:0.003`` (m, random
via-point shifts; the
nuisance a body schema learns, not a diagnosis target). The shifts are drawn from the run's
seed unless the spec names its own, ``routing:0.004,seed=3``: one arm, whatever poses a
collection draws (a schema learned on one collection is used on another).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from pimbs_arm.model import ArmModel

# Vocabulary shared with the diagnosis report; aliases accepted on the command line.
EFFECT_NAMES = ("tendon_friction", "link_mass", "tension_offset", "tension_gain",
                "thermal_drift", "elastic_stiffness", "joint_offset", "routing", "joint_spring")
ALIASES = {"friction": "tendon_friction", "mass": "link_mass", "offset": "tension_offset",
           "loadcell_offset": "tension_offset", "drift": "thermal_drift",
           "gain": "tension_gain", "loadcell_gain": "tension_gain",
           "stiffness": "elastic_stiffness", "encoder_offset": "joint_offset",
           "spring": "joint_spring"}
DEFAULT_MAGNITUDE = {"tendon_friction": 0.15, "link_mass": 1.3, "tension_offset": 15.0,
                     "tension_gain": 0.15,
                     "thermal_drift": 0.8, "elastic_stiffness": 0.6, "joint_offset": 0.04,
                     "routing": 0.002, "joint_spring": 1.0}
T_REF = 25.0  # °C at which loadcells are calibrated
# magnitude -> (what it is, lowest, highest, lowest excluded): physical and simulable values
MAGNITUDE_RANGE = {
    "tendon_friction": ("friction coefficient mu", 0.0, 1.0, False),
    "link_mass": ("mass scale", 0.0, 10.0, True),
    "tension_offset": ("loadcell offset [N]", -500.0, 500.0, False),
    "tension_gain": ("loadcell gain error (reads (1+g)·f)", -0.9, 10.0, False),
    "thermal_drift": ("drift [N/°C]", -50.0, 50.0, False),
    "elastic_stiffness": ("stiffness scale K_true/K_model", 0.0, 10.0, True),
    "joint_offset": ("joint zero offset [rad]", -0.5, 0.5, False),
    "routing": ("via-point shift [m]", 0.0, 0.02, False),
    "joint_spring": ("passive joint spring rate [N*m/rad]", 0.0, 1000.0, True),
}


class EffectSpecError(ValueError):
    """A ``--conceal`` spec that cannot be understood; the message says the accepted form."""


@dataclass
class Effect:
    """One concealed effect with its parameters (all in SI units)."""

    name: str
    magnitude: float
    muscles: tuple[str, ...] = ()  # empty: all muscles
    joints: tuple[str, ...] = ()   # empty: the first joint (joint_offset)
    link: str | None = None        # link_mass: None -> the last moving link
    seed: int = 0                  # routing: which random shifts
    extra: dict[str, Any] = field(default_factory=dict)

    # -- the three places an effect acts ------------------------------------------------
    def physics(self, arm: ArmModel) -> ArmModel:
        """The true arm: the model arm changed where this effect changes physics."""
        if self.name in ("link_mass", "routing") and arm.backend.kind == "mjcf":
            return self._mjcf_physics(arm)
        if self.name == "link_mass":
            return _with_link_mass(arm, self.link or _last_link(arm), self.magnitude)
        if self.name == "elastic_stiffness":
            scale = np.ones(arm.n_muscles)
            scale[self._muscle_mask(arm)] = self.magnitude
            true_arm = copy.copy(arm)
            true_arm.K = arm.K * scale
            return true_arm
        if self.name == "routing":
            rng = np.random.default_rng([self.seed, 77])
            return _with_via_point_shifts(arm, rng.normal(0.0, self.magnitude,
                                                          arm.backend._via_local.shape))
        if self.name == "joint_spring":
            rate = self.at_joints(arm)
            rest = np.where(rate != 0, float(self.extra.get("rest", 0.0)), 0.0)
            return arm.with_backend(SprungBackend(arm.backend, rate, rest))
        return arm

    def _mjcf_physics(self, arm: ArmModel) -> ArmModel:
        """link_mass and routing on an MJCF arm: a body's mass, or the tendons' sites moved
        (the MuJoCo backend measures the changed model as it does the description)."""
        backend = arm.backend
        if self.name == "link_mass":
            try:
                changed = backend.with_body_mass(self.link or backend.last_body(),
                                                 self.magnitude)
            except ValueError as exc:
                raise EffectSpecError(f"link_mass: {exc}") from exc
            return arm.with_backend(changed)
        rng = np.random.default_rng([self.seed, 77])
        shifts = rng.normal(0.0, self.magnitude, (len(backend.muscle_sites()), 3))
        return arm.with_backend(backend.with_site_shifts(shifts))

    def true_pose(self, arm: ArmModel, theta_cmd: np.ndarray) -> np.ndarray:
        """Where the arm really is when the (possibly offset) joint sensor says θ_cmd."""
        if self.name != "joint_offset":
            return theta_cmd
        return theta_cmd - self.at_joints(arm)

    def read_tension(self, arm: ArmModel, tension: np.ndarray, approach: np.ndarray,
                     temperature: np.ndarray) -> np.ndarray:
        """What the loadcells read given the joint-side tension (no noise added here)."""
        mask = self._muscle_mask(arm)
        out = np.array(tension, dtype=float, copy=True)
        if self.name == "tendon_friction":
            out[..., mask] *= np.exp(-np.asarray(approach, float)[..., mask] * self.magnitude)
        elif self.name == "tension_gain":
            out[..., mask] *= 1.0 + self.magnitude
        elif self.name == "tension_offset":
            out[..., mask] += self.magnitude
        elif self.name == "thermal_drift":
            out[..., mask] += self.magnitude * (np.asarray(temperature)[..., mask] - T_REF)
        return out

    # -- helpers ------------------------------------------------------------------------
    def at_joints(self, arm: ArmModel) -> np.ndarray:
        """(N,) the magnitude at the named joints (the first joint when none is named), zero
        elsewhere: a joint offset's δ, a joint spring's rate."""
        delta = np.zeros(arm.n_joints)
        names = self.joints or (arm.joints[0],)
        for name in names:
            delta[_index(arm.joints, name, "joint")] = self.magnitude
        return delta

    def _muscle_mask(self, arm: ArmModel) -> np.ndarray:
        mask = np.zeros(arm.n_muscles, dtype=bool)
        if not self.muscles:
            mask[:] = True
        for name in self.muscles:
            mask[_index(arm.muscles, name, "muscle")] = True
        return mask

    def describe(self) -> str:
        parts = [f"{self.name}:{self.magnitude:g}"]
        if self.muscles:
            parts.append("muscles=" + "+".join(self.muscles))
        if self.joints:
            parts.append("joints=" + "+".join(self.joints))
        if self.link:
            parts.append(f"link={self.link}")
        if "rest" in self.extra:
            parts.append(f"rest={self.extra['rest']:g}")
        return ",".join(parts)


def _last_link(arm: ArmModel) -> str:
    """The link carried by the last actuated joint (the forearm, hand...)."""
    model = arm._model
    last = model.getJointId(arm.joints[-1])
    for frame in model.frames:
        if frame.type == pin.FrameType.BODY and frame.parentJoint == last:
            return frame.name
    raise EffectSpecError(f"{arm.robot.name}: no link on joint {arm.joints[-1]}")


def _with_link_mass(arm: ArmModel, link: str, scale: float) -> ArmModel:
    """Copy of ``arm`` whose ``link`` weighs ``scale`` times as much (same centre of mass).

    Pinocchio merges links fixed to one joint; the scale applies to that merged body.
    """
    model = pin.Model(arm._model)
    if not model.existBodyName(link):
        raise EffectSpecError(f"unknown link '{link}' in {arm.robot.urdf_path.name}")
    joint = model.frames[model.getBodyId(link)].parentJoint
    body = model.inertias[joint]  # the link (and any links fixed to it), in the joint frame
    if joint == 0 or body.mass <= 0:
        raise EffectSpecError(f"link '{link}' has no mass on a moving joint in "
                              f"{arm.robot.urdf_path.name}")
    model.inertias[joint] = pin.Inertia(body.mass * scale, body.lever, body.inertia * scale)
    return arm.with_backend(arm.backend.fresh(model=model))


class SprungBackend:
    """An arm backend with a passive spring at some joints: the muscles also hold
    ``rate·(θ − rest)``, as MuJoCo's joint ``stiffness`` and ``springref`` pull. Everything
    else is the wrapped backend's."""

    def __init__(self, inner, rate: np.ndarray, rest: np.ndarray):
        self._inner = inner
        self._rate, self._rest = np.asarray(rate, float), np.asarray(rest, float)

    def __getattr__(self, name: str):
        if name.startswith("__"):  # copies and pickles look these up before __init__ ran
            raise AttributeError(name)
        return getattr(self.__dict__["_inner"], name)

    def gravity(self, theta: np.ndarray) -> np.ndarray:
        return self._inner.gravity(theta) + self._rate * (np.asarray(theta) - self._rest)

    def gravity_derivative(self, theta: np.ndarray) -> np.ndarray:
        return self._inner.gravity_derivative(theta) + np.diag(self._rate)

    def potential_energy(self, theta: np.ndarray) -> float:
        stretch = np.asarray(theta) - self._rest
        return self._inner.potential_energy(theta) + 0.5 * float(self._rate @ stretch**2)


def _with_via_point_shifts(arm: ArmModel, shifts: np.ndarray) -> ArmModel:
    """Copy of ``arm`` whose via points sit ``shifts`` (V, 3) metres from the model's."""
    return arm.with_backend(arm.backend.fresh(via_local=arm.backend._via_local + shifts))


def _index(names: list[str] | tuple[str, ...], name: str, what: str) -> int:
    try:
        return list(names).index(name)
    except ValueError:
        raise EffectSpecError(f"unknown {what} '{name}'; this robot has "
                              f"{', '.join(names)}") from None


def parse_effect(spec: str, seed: int = 0) -> Effect:
    """Parse ``NAME[:MAGNITUDE][,key=value...]`` (``muscles``/``joints`` joined by ``+``)."""
    name, _, params = spec.partition(":")
    name = ALIASES.get(name.strip(), name.strip())
    if name not in EFFECT_NAMES:
        raise EffectSpecError(f"unknown effect '{name}' in '{spec}'; choose one of "
                              f"{', '.join(EFFECT_NAMES)} (or an alias: "
                              f"{', '.join(ALIASES)})")
    effect = Effect(name=name, magnitude=DEFAULT_MAGNITUDE[name], seed=seed)
    for i, item in enumerate(p for p in params.split(",") if p.strip()):
        key, eq, value = item.partition("=")
        try:
            if not eq and i == 0:
                effect.magnitude = float(key)
            elif key in ("muscles", "muscle"):
                effect.muscles = tuple(value.split("+"))
            elif key in ("joints", "joint"):
                effect.joints = tuple(value.split("+"))
            elif key == "link":
                effect.link = value
            elif key == "seed":  # which arm: the same routing for every pose sequence
                effect.seed = int(value)
            elif key == "rest" and name == "joint_spring":  # rad: the angle it pulls toward
                effect.extra["rest"] = float(value)
            elif key in ("magnitude", "value", "mu", "scale", "offset", "coef", "gain"):
                effect.magnitude = float(value)
            else:
                raise EffectSpecError(f"unknown parameter '{key}' in '{spec}'")
        except ValueError as exc:
            if isinstance(exc, EffectSpecError):
                raise
            raise EffectSpecError(f"'{item}' in '{spec}' is not a number; the form is "
                                  f"NAME[:MAGNITUDE][,muscles=m0+m1][,joints=j][,link=l]"
                                  ) from None
    _check_magnitude(effect, spec)
    return effect


def _check_magnitude(effect: Effect, spec: str) -> None:
    """Refuse a magnitude outside its physical range before it reaches the physics
    (a negative mass would only surface as a pinocchio message about inertia)."""
    what, lo, hi, lo_open = MAGNITUDE_RANGE[effect.name]
    v = effect.magnitude
    if np.isfinite(v) and (lo < v if lo_open else lo <= v) and v <= hi:
        return
    bracket = "(" if lo_open else "["
    raise EffectSpecError(
        f"'{spec}': {effect.name} {what} must be in {bracket}{lo:g}, {hi:g}], not {v:g} "
        f"(default {DEFAULT_MAGNITUDE[effect.name]:g})")


@dataclass
class World:
    """The true arm a set of concealed effects makes of the model arm.

    ``model`` is what the tools believe (it computes ``tau_gravity``); ``arm`` is the
    physics the data obey.
    """

    model: ArmModel
    effects: tuple[Effect, ...] = ()

    def __post_init__(self) -> None:
        arm = self.model
        for effect in self.effects:
            effect._muscle_mask(self.model)  # validate names early
            if effect.name == "joint_offset":
                effect.at_joints(self.model)
            arm = effect.physics(arm)
        self.arm = arm

    def true_pose(self, theta_cmd: np.ndarray) -> np.ndarray:
        theta = np.asarray(theta_cmd, dtype=float)
        for effect in self.effects:
            theta = effect.true_pose(self.model, theta)
        return theta

    def read_tension(self, tension: np.ndarray, approach: np.ndarray,
                     temperature: np.ndarray) -> np.ndarray:
        out = np.asarray(tension, dtype=float)
        for effect in self.effects:
            out = effect.read_tension(self.model, out, approach, temperature)
        return out
