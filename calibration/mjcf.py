"""What an MJCF (MuJoCo's XML) says about a tendon-driven arm: joints, tendons, actuator limits.

An arm already described in MuJoCo should not have to be re-typed as via points: its spatial
tendons (through sites, wrapping around spheres and cylinders, split by pulleys) are the
muscles, its hinge joints the joints they drive. This module only reads the file, compiled by
MuJoCo itself (so ``<default>`` classes, ``<include>``, degrees vs radians and every other
MJCF rule mean what MuJoCo says they mean); ``description.py`` turns what it finds into a
``RobotDescription`` and MuJoCo measures the tendons (``pimbs_arm.backends.mujoco_tendons``).

Unnamed objects get the names MuJoCo's own viewer would show them by: ``joint<i>``,
``tendon<i>`` (index in file order), unless the file itself uses that name for another
object (then ``joint<i>_unnamed``): a generated name never collides with one the file
gives. ``<equality><joint>`` couplings are read as ``JointCoupling`` (see ``coupling``).
``MjcfError`` names the file and what to do.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from pimbs_calibration.coupling import JointCoupling

_JOINT_TYPES = {int(mujoco.mjtJoint.mjJNT_FREE): "free", int(mujoco.mjtJoint.mjJNT_BALL): "ball",
                int(mujoco.mjtJoint.mjJNT_SLIDE): "slide",
                int(mujoco.mjtJoint.mjJNT_HINGE): "hinge"}
_WRAP_NAMES = {int(mujoco.mjtWrap.mjWRAP_SITE): "site", int(mujoco.mjtWrap.mjWRAP_SPHERE): "sphere",
               int(mujoco.mjtWrap.mjWRAP_CYLINDER): "cylinder",
               int(mujoco.mjtWrap.mjWRAP_PULLEY): "pulley"}


class MjcfError(ValueError):
    """An MJCF cannot serve as a robot description; the message names the file and the fix."""

    def __init__(self, path: Path, problem: str, fix: str) -> None:
        self.path, self.problem, self.fix = Path(path), problem, fix
        super().__init__(f"{self.path}: {problem}. {fix}")


@dataclass(frozen=True)
class MjcfJoint:
    """One joint of the compiled model (angles in rad whatever ``<compiler angle>`` says)."""

    name: str
    type: str  # hinge | slide | ball | free
    limited: bool
    range: tuple[float, float]  # (lo, hi); meaningless unless limited
    qpos0: float  # reference position of a hinge/slide (where it is locked if not driven)


@dataclass(frozen=True)
class MjcfTendon:
    """One tendon: spatial ones can be muscles; fixed ones (joint couplings) cannot."""

    name: str
    spatial: bool
    route: tuple[str, ...]  # "site a", "cylinder pulley_geom", "pulley /2", ... in file order
    force_limit: float | None  # largest tension an actuator on it declares, N
    force_source: str | None  # where force_limit comes from, in words ("muscle actuator 'x'
    # (its peak force)")
    length_range: tuple[float, float] | None  # the tendon's own length limits (m), if limited


@dataclass(frozen=True)
class MjcfArm:
    """The parts of an MJCF that a robot description is built from."""

    path: Path
    name: str  # <mujoco model="..."> (MuJoCo's default "MuJoCo Model" -> the file stem)
    joints: tuple[MjcfJoint, ...]
    tendons: tuple[MjcfTendon, ...]
    couplings: tuple[JointCoupling, ...] = ()  # every <equality><joint>, active or not
    other_equalities: tuple[str, ...] = ()  # "weld 'x'", ...: not joint couplings

    def hinge_names(self) -> list[str]:
        return [j.name for j in self.joints if j.type == "hinge"]

    def spatial_names(self) -> list[str]:
        return [t.name for t in self.tendons if t.spatial]


def is_mjcf(path: Path) -> bool:
    """True for a readable ``.xml`` whose root element is ``<mujoco>`` (a URDF's is ``<robot>``)."""
    if path.suffix.lower() != ".xml" or not path.is_file():
        return False
    try:
        for _, element in ET.iterparse(path, events=("start",)):
            return element.tag == "mujoco"
    except (ET.ParseError, OSError):
        return False
    return False


def compile_model(path: Path) -> mujoco.MjModel:
    """MuJoCo's compiled model of an MJCF file; its parse/compile errors become one line.

    The muscle actuators' length ranges are not computed (``<compiler><lengthrange
    mode="none">``): PIMBS's muscles are the tendons, driven by its boards, not MJCF
    actuators, and that computation (a simulation per actuator) can fail to converge on a
    model that is otherwise fine.
    """
    try:
        spec = mujoco.MjSpec.from_file(str(path))
        options = getattr(spec.compiler, "LRopt", None)
        if options is not None:
            options.mode = mujoco.mjtLRMode.mjLRMODE_NONE
        return spec.compile()
    except ValueError as exc:  # MuJoCo: "XML Error: ... Element 'x', line n"
        problem = " ".join(str(exc).split())
        raise MjcfError(path, f"MuJoCo cannot load this MJCF ({problem})",
                        "Fix the file so that MuJoCo's own viewer opens it") from exc


def joint_names(model: mujoco.MjModel) -> list[str]:
    """Every joint's name; unnamed ones ``joint<i>`` (see ``_named``)."""
    return _named([model.joint(i).name for i in range(model.njnt)], "joint")


def tendon_names(model: mujoco.MjModel) -> list[str]:
    """Every tendon's name; unnamed ones ``tendon<i>`` (see ``_named``)."""
    return _named([model.tendon(i).name for i in range(model.ntendon)], "tendon")


def _named(names: list[str], kind: str) -> list[str]:
    """The file's names, and for an unnamed object ``<kind><i>`` (i its index), or, where the
    file calls another object that, ``<kind><i>_unnamed`` (with ``_`` added until free)."""
    taken = {n for n in names if n}
    out = []
    for i, name in enumerate(names):
        if not name:
            name = f"{kind}{i}"
            if name in taken:
                name += "_unnamed"
                while name in taken:
                    name += "_"
            taken.add(name)
        out.append(name)
    return out


def joint_couplings(model: mujoco.MjModel) -> list[JointCoupling]:
    """Every ``<equality><joint>`` of the compiled model, in file order (active or not)."""
    joints = joint_names(model)
    names = _named([model.eq(i).name for i in range(model.neq)], "equality")
    out = []
    for i in range(model.neq):
        if int(model.eq_type[i]) != int(mujoco.mjtEq.mjEQ_JOINT):
            continue
        follower, leader = int(model.eq_obj1id[i]), int(model.eq_obj2id[i])
        ref = model.qpos0[model.jnt_qposadr[follower]]
        lead_ref = model.qpos0[model.jnt_qposadr[leader]] if leader >= 0 else 0.0
        out.append(JointCoupling(
            equality=names[i], follower=joints[follower],
            leader=joints[leader] if leader >= 0 else None,
            coef=tuple(float(c) for c in model.eq_data[i, :5]), follower_ref=float(ref),
            leader_ref=float(lead_ref), active=bool(model.eq_active0[i])))
    return out


def _other_equalities(model: mujoco.MjModel) -> tuple[str, ...]:
    """The equalities that are not joint couplings, in words (``weld 'x'``)."""
    names = _named([model.eq(i).name for i in range(model.neq)], "equality")
    return tuple(f"{mujoco.mjtEq(int(model.eq_type[i])).name.removeprefix('mjEQ_').lower()} "
                 f"'{names[i]}'" for i in range(model.neq)
                 if int(model.eq_type[i]) != int(mujoco.mjtEq.mjEQ_JOINT))


def read_mjcf(path: Path) -> MjcfArm:
    """Compile ``path`` and list its joints and tendons. Raises ``MjcfError``."""
    model = compile_model(path)
    joints = []
    for i, name in enumerate(joint_names(model)):
        kind = _JOINT_TYPES[int(model.jnt_type[i])]
        qpos0 = float(model.qpos0[model.jnt_qposadr[i]]) if kind in ("hinge", "slide") else 0.0
        lo, hi = (float(v) for v in model.jnt_range[i])
        joints.append(MjcfJoint(name=name, type=kind, limited=bool(model.jnt_limited[i]),
                                range=(lo, hi), qpos0=qpos0))
    limits = _actuator_force_limits(model)
    tendons = []
    for i, name in enumerate(tendon_names(model)):
        types = model.wrap_type[model.tendon_adr[i]:model.tendon_adr[i] + model.tendon_num[i]]
        spatial = int(types[0]) != int(mujoco.mjtWrap.mjWRAP_JOINT)
        length_range = (tuple(float(v) for v in model.tendon_range[i])
                        if model.tendon_limited[i] else None)
        limit, source = limits.get(i, (None, None))
        tendons.append(MjcfTendon(name=name, spatial=spatial,
                                  route=_route(model, i) if spatial else (),
                                  force_limit=limit, force_source=source,
                                  length_range=length_range))
    return MjcfArm(path=path, name=_model_name(path, model), joints=tuple(joints),
                   tendons=tuple(tendons), couplings=tuple(joint_couplings(model)),
                   other_equalities=_other_equalities(model))


def _model_name(path: Path, model: mujoco.MjModel) -> str:
    name = model.names[:model.names.index(b"\0")].decode()  # the model name comes first
    return path.stem if name in ("", "MuJoCo Model") else name


def _route(model: mujoco.MjModel, tendon: int) -> tuple[str, ...]:
    """The tendon's path in words: the sites it runs through, the geoms it wraps, pulleys."""
    out = []
    start = model.tendon_adr[tendon]
    for k in range(start, start + model.tendon_num[tendon]):
        kind = _WRAP_NAMES.get(int(model.wrap_type[k]), "?")
        obj = int(model.wrap_objid[k])
        if kind == "site":
            out.append(f"site {model.site(obj).name or obj}")
        elif kind == "pulley":
            out.append(f"pulley /{model.wrap_prm[k]:g}")
        else:
            out.append(f"{kind} {model.geom(obj).name or obj}")
    return tuple(out)


def _actuator_force_limits(model: mujoco.MjModel) -> dict[int, tuple[float, str]]:
    """Tendon id -> the largest tension an actuator on it declares (N), and which actuator
    declares it how, in words.

    A force-limited actuator declares its largest |forcerange|; a MuJoCo muscle that is not
    force-limited declares its peak active force F0 (``force``, or MuJoCo's own rule when
    that is negative: ``scale / acc0``); a control-limited ``<motor>`` (a fixed gain, no
    bias) its largest |ctrlrange| times its gain. The tendon carries |gear| times the
    actuator's force. Several actuators on one tendon: the largest.
    """
    limits: dict[int, tuple[float, str]] = {}
    for a in range(model.nu):
        if int(model.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_TENDON):
            continue
        name = model.actuator(a).name or f"actuator{a}"
        if model.actuator_forcelimited[a]:
            bound = float(np.abs(model.actuator_forcerange[a]).max())
            how = f"the forcerange of actuator '{name}'"
        elif int(model.actuator_gaintype[a]) == int(mujoco.mjtGain.mjGAIN_MUSCLE):
            bound = _muscle_peak_force(model, a)
            how = f"the peak force of muscle actuator '{name}'"
        elif (model.actuator_ctrllimited[a]
              and int(model.actuator_gaintype[a]) == int(mujoco.mjtGain.mjGAIN_FIXED)
              and int(model.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_NONE)):
            bound = float(np.abs(model.actuator_ctrlrange[a]).max()
                          * abs(model.actuator_gainprm[a, 0]))
            how = f"the ctrlrange x gain of motor '{name}'"
        else:
            continue
        gear = abs(float(model.actuator_gear[a, 0]))
        bound *= gear
        if gear != 1:
            how += f" x gear {gear:g}"
        tendon = int(model.actuator_trnid[a, 0])
        if bound > 0 and bound > limits.get(tendon, (0.0, ""))[0]:
            limits[tendon] = (bound, how)
    return limits


def _muscle_peak_force(model: mujoco.MjModel, actuator: int) -> float:
    """A muscle actuator's peak active force F0 (N): ``force`` (gainprm[2]), or, where that
    is negative, the rule MuJoCo's muscle gain applies at every step: ``scale / acc0``."""
    force, scale = (float(v) for v in model.actuator_gainprm[actuator, 2:4])
    if force >= 0:
        return force
    return scale / max(float(model.actuator_acc0[actuator]), mujoco.mjMINVAL)
