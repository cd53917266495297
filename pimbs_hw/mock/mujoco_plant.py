"""MuJoCo as the true arm behind the simulated boards: real dynamics with ``mj_step``.

The quasi-static plant (``plant.py``) jumps to the arm model's equilibrium and relaxes toward
it; a real arm swings, overshoots, rubs and settles. This plant integrates an MJCF with
MuJoCo (inertia, joint damping and armature, tendon friction loss and damping, wrapping, as
the file says; its own actuators are disabled), each muscle a motor winding its tendon
through the series elastic element of the description (f = exp(K·Δn) − 1, Δn = tendon
length − motor length, slack pulls nothing). The loadcell reads that tension, the motor
encoder the motor length, the joint encoders the joint angles: what the boards report,
never the model's equilibrium.

The plant MJCF may differ from the description (a pulley radius, a via point, a mass the
description got wrong: the "real" arm); it must name the description's joints (hinges) and
muscles (spatial tendons). Joints of the plant that the description does not drive are held
at their reference ``qpos0`` (or the description's ``locked`` value), except the followers
of the plant's own ``<equality><joint>`` couplings whose chain of leaders starts at a driven
joint: MuJoCo's equality constraint stays active and moves them with their leaders, as the
plant file says (they start where the coupling puts them).

Length-mode motors follow their command with a first-order servo (``motor_tau_s``); a
tension-mode board's force loop is modelled as a first-order lag to the commanded tension,
the motor paying out or winding in whatever length that takes. The tension each substep is
computed from the state after MuJoCo's position stage (``mj_step1``) and applied as the
generalized force −Jᵀf before the integration (``mj_step2``), the split MuJoCo documents for
forces that depend on the current state.
"""

from __future__ import annotations

import itertools
import sys
import threading
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import mujoco
import numpy as np
import scipy.linalg

from pimbs_calibration.coupling import CoupledJoints, CouplingError, coupling_order, moved_by
from pimbs_calibration.mjcf import (
    MjcfError,
    compile_model,
    joint_couplings,
    joint_names,
    tendon_names,
)
from pimbs_hw.mock.plant import (
    HEAT_AT_F_MAX_C,
    PlantState,
    heat_per_newton,
    power_up,
    thermal_step,
)
from pimbs_recording.approach import FrictionPlay

_EXP_CAP = 60.0  # cap K*dn: a tension beyond e^60 N is a broken simulation, not a number
SETTLED_SPEED = 1e-3  # rad/s: joints slower than this for REST_S (motors at their targets)
REST_S = 0.2  # s of arm time: a swing's turning point is slow only for an instant
RING_TARGET_S = 0.5  # s: the decay time the suggested joint damping gives the plant arm
# share of the stability limit 2/ω a step may take: ω is that of every wire at f_max at once,
# beyond any state a collection holds, and the elastic law stiffens within a swing
STEP_SHARE = 0.8
MAX_SPEED = 1e3  # rad/s: no arm's joint turns faster; beyond it the integration blew up


_QUIET = threading.local()  # set while this thread steps a plant: MuJoCo's warnings are ours


def _quiet_mujoco_warnings() -> None:
    """Route MuJoCo's warnings through a handler that drops them while a plant steps (the
    plant reads MuJoCo's warning counters and reports in its own words) and prints them as
    MuJoCo would otherwise."""
    if getattr(_quiet_mujoco_warnings, "installed", False):
        return
    previous = mujoco.get_mju_user_warning()

    def handler(message: str) -> None:
        if getattr(_QUIET, "on", False):
            return
        if previous is not None:
            previous(message)
        else:
            print(f"WARNING: {message}", file=sys.stderr)

    mujoco.set_mju_user_warning(handler)
    _quiet_mujoco_warnings.installed = True


class PlantMismatch(ValueError):
    """The plant MJCF does not fit the description (message names both and what is missing)."""


def _compile(xml: Path) -> mujoco.MjModel:
    """The plant MJCF, compiled; a file MuJoCo cannot load is one ``PlantMismatch`` line."""
    try:
        return compile_model(xml)
    except MjcfError as exc:
        raise PlantMismatch(f"--plant {exc}") from exc


def _driven(mj: mujoco.MjModel, robot, xml: Path) -> tuple[list[int], np.ndarray]:
    """The plant's joint ids of the description's driven joints (hinges) and its tendon ids
    of the description's muscles, by name; ``PlantMismatch`` naming what is missing."""
    joints, tendons = joint_names(mj), tendon_names(mj)
    hinge = int(mujoco.mjtJoint.mjJNT_HINGE)
    bad = [j for j in robot.joints
           if j not in joints or int(mj.jnt_type[joints.index(j)]) != hinge]
    if bad:
        raise PlantMismatch(
            f"--plant {xml}: no hinge joint named {', '.join(bad)} (the description "
            f"{robot.muscle_path} drives {', '.join(robot.joints)}); name the plant's "
            "joints as the description does")
    muscles = [mu.name for mu in robot.muscles]
    missing = [t for t in muscles if t not in tendons]
    if missing:
        raise PlantMismatch(
            f"--plant {xml}: no tendon named {', '.join(missing)} (the description "
            f"{robot.muscle_path} has muscles {', '.join(muscles)}); name one spatial "
            "tendon of the plant after each muscle")
    return ([joints.index(j) for j in robot.joints],
            np.array([tendons.index(t) for t in muscles], dtype=int))


def _coupled(mj: mujoco.MjModel, robot, xml: Path) -> CoupledJoints:
    """The description's driven joints in the plant and the plant's followers they move
    (through the plant's own active joint equalities)."""
    try:
        couplings = {c.follower: c for c in coupling_order(joint_couplings(mj))}
    except CouplingError as exc:
        raise PlantMismatch(f"--plant {xml}: {exc}; keep one active <equality><joint> per "
                            "follower joint") from exc
    names = joint_names(mj)
    return CoupledJoints(robot.joints, moved_by(couplings, robot.joints),
                         {n: int(mj.jnt_qposadr[i]) for i, n in enumerate(names)},
                         {n: int(mj.jnt_dofadr[i]) for i, n in enumerate(names)})


@dataclass(frozen=True)
class Ringing:
    """How long the plant arm rings once disturbed, and the joint damping that would calm it.

    Held by its wires, the arm is a mass on springs: only the plant's joint and tendon damping
    take the energy of each load step out (the MJCF's own actuators, muscles included, are
    off: the boards drive the tendons). Every motion of the driven joints decays at least as
    fast as exp(-t / ``decay_s``), whatever the wires' stiffness: ``decay_s`` = 2 / (smallest
    eigenvalue of M⁻¹D), M the joint-space inertia (armature included), D the damping,
    the worst over the centre and corners of the joint ranges (256 of the corners, drawn with
    a fixed seed, for an arm of more than 8 driven joints).
    """

    decay_s: float          # inf: some motion of the joints is not damped at all
    damping: np.ndarray     # (N,) the driven joints' own damping, N·m·s/rad
    suggested: np.ndarray   # (N,) joint damping: no pose rings past RING_TARGET_S

    def calming(self, joints: tuple[str, ...], wait_s: float) -> dict[str, float]:
        """The joint damping (joint name → N·m·s/rad) that calms an arm ringing longer than
        ``wait_s`` (a pose's settle timeout): the suggestion where it is above the file's;
        {} for an arm that settles in time."""
        if self.decay_s <= wait_s:
            return {}
        return {j: float(want) for j, want, now in zip(joints, self.suggested, self.damping,
                                                      strict=True) if want > now}

    def note(self, xml: Path, joints: tuple[str, ...], wait_s: float,
             calmed: bool = False) -> str:
        """One line when the arm rings longer than ``wait_s`` (a pose's settle timeout), else
        '': a note that the run damps it (``calmed``, see ``calming``), else a warning."""
        if self.decay_s <= wait_s:
            return ""
        took = "never dies down" if not np.isfinite(self.decay_s) else \
            f"takes {self.decay_s:.0f} s to die down to 1/e"
        now = ", ".join(f"{d:g}" for d in self.damping)
        want = ", ".join(f"{j} {d:.2g}" for j, d in self.calming(joints, wait_s).items())
        rings = (f"the plant {xml} is barely damped: a motion of its joints {took} (joint "
                 f"damping {now} N·m·s/rad), longer than the {wait_s:g} s a pose may take to "
                 "settle. A real arm's motors, gears and wires damp it (MuJoCo muscle "
                 "actuators would too, but the boards drive the tendons)")
        if calmed:
            return (f"note: {rings}: this run gives the plant's joints damping of {want} "
                    "N·m·s/rad (--plant-damping file runs the file's own)")
        return (f"warning: {rings}, so held poses will ring and a wire may reach its tension "
                f"ceiling: give the plant's joints damping of about {want} N·m·s/rad, or its "
                "tendons damping")


@dataclass(frozen=True)
class _Pose:
    """The plant arm at one pose, in the driven joints' coordinates: the followers of its
    joint couplings move with their leaders (``S``; the identity without couplings)."""

    inertia: np.ndarray  # (N, N) joint-space inertia, armature included
    jac: np.ndarray      # (ntendon, N) every tendon's Jacobian
    S: np.ndarray        # (len(columns), N) d(moved dofs)/d(driven joints)

    def joints(self, per_dof: np.ndarray) -> np.ndarray:
        """(N, N) of a per-dof diagonal (damping, stiffness) of the moved dofs: SᵀDS."""
        return self.S.T @ (per_dof[:, None] * self.S)


def _reduce(mj: mujoco.MjModel, data: mujoco.MjData, coupled: CoupledJoints,
            jac: np.ndarray) -> _Pose:
    """``_Pose`` of ``data`` (positions forwarded, followers placed; ``jac`` its dense tendon
    Jacobian (ntendon, nv))."""
    full_m = np.zeros((mj.nv, mj.nv))
    mujoco.mj_fullM(mj, data, full_m)
    cols = coupled.columns
    S = coupled.jacobian(data.qpos)
    return _Pose(inertia=S.T @ full_m[np.ix_(cols, cols)] @ S, jac=jac[:, cols] @ S, S=S)


def _sweep(mj: mujoco.MjModel, robot, xml: Path
           ) -> tuple[list[int], np.ndarray, CoupledJoints, list[_Pose]]:
    """The driven dofs, the muscles' tendon ids, the driven joints with the followers they
    move, and the arm (``_Pose``) at the centre and corners of the joint ranges (others held
    at the plant's reference pose, followers where their couplings put them)."""
    jid, tendons = _driven(mj, robot, xml)
    qadr, dof = mj.jnt_qposadr[jid], mj.jnt_dofadr[jid]
    coupled = _coupled(mj, robot, xml)
    data = mujoco.MjData(mj)
    jac = np.zeros((mj.ntendon, mj.nv))
    lo, hi = np.asarray(robot.joint_range, float).T
    out = []
    for theta in [(lo + hi) / 2] + _corners(lo, hi):
        data.qpos[:] = mj.qpos0
        data.qpos[qadr] = theta
        coupled.place(data.qpos)
        mujoco.mj_forward(mj, data)
        mujoco.mju_sparse2dense(jac, data.ten_J, mj.ten_J_rownnz, mj.ten_J_rowadr,
                                mj.ten_J_colind)
        out.append(_reduce(mj, data, coupled, jac))
    return list(dof), tendons, coupled, out


def ringing(xml: Path, robot) -> Ringing:
    """``Ringing`` of the plant MJCF ``xml`` driven as ``robot`` describes (its joints and
    muscles by name, others locked as the plant holds them)."""
    mj = _compile(Path(xml))
    dof, _, coupled, sweep = _sweep(mj, robot, Path(xml))
    decay = 0.0
    for pose in sweep:
        damping = (pose.joints(mj.dof_damping[coupled.columns])
                   + pose.jac.T @ np.diag(mj.tendon_damping) @ pose.jac)
        decay = max(decay, _decay_s(damping, pose.inertia))
    inertias = [pose.inertia for pose in sweep]
    # joint damping in proportion to each joint's largest inertia, scaled so that no pose
    # rings longer than RING_TARGET_S (decay scales as 1/damping; the tendons' only adds)
    shape = np.max([np.diag(m) for m in inertias], axis=0)
    scale = max(_decay_s(np.diag(shape), m) for m in inertias) / RING_TARGET_S
    return Ringing(decay_s=decay, damping=np.array(mj.dof_damping[dof]),
                   suggested=np.maximum(mj.dof_damping[dof], scale * shape))


def _corners(lo: np.ndarray, hi: np.ndarray, most: int = 256) -> list[np.ndarray]:
    """The corners of the joint ranges, or, where there are more than ``most`` (a 27-joint
    arm has 134 million), ``most`` of them drawn with a fixed seed."""
    if 2 ** len(lo) <= most:
        return [np.array(c) for c in itertools.product(*zip(lo, hi, strict=True))]
    pick = np.random.default_rng(0).integers(0, 2, (most, len(lo))).astype(bool)
    return list(np.where(pick, hi, lo))


@dataclass(frozen=True)
class Timestep:
    """The plant's timestep against its stiffest element.

    MuJoCo integrates the series elastic elements' force explicitly (it is computed from the
    positions, then integrated), so a swing of angular frequency ω is stable only while
    ω·dt < 2, and the elastic law stiffens as it swings (df/dl = K(f + 1)). ω is largest with
    every wire at its f_max (the boards' ceiling): the largest eigenvalue of M⁻¹S, S the
    joint-space stiffness of the wires, the tendons' and joints' own springs, M the inertia
    with armature, the worst over the centre and corners of the joint ranges. The plant
    steps at most ``STEP_SHARE``·2/ω: the file's timestep where that is fine, else the file's
    timestep divided into as many equal steps as it takes.
    """

    file_s: float   # the plant file's <option timestep>
    omega: float    # rad/s, the fastest swing of its stiffest state
    muscle: str     # the wire that stiffens the fastest swing most
    f_max: float    # N, that wire's f_max

    @property
    def needed_s(self) -> float:
        return STEP_SHARE * 2.0 / self.omega if self.omega > 0 else np.inf

    @property
    def step_s(self) -> float:
        """The step the plant integrates with."""
        return self.file_s / max(1, int(np.ceil(self.file_s / self.needed_s - 1e-9)))

    def note(self, xml: Path) -> str:
        """One line when the plant must step finer than its file says, else ''."""
        if self.step_s >= self.file_s:
            return ""
        return (f"note: the plant {xml} is integrated with {self.step_s * 1e3:.3g} ms steps, "
                f"not its file's {self.file_s * 1e3:.3g} ms: at its f_max ({self.f_max:.0f} N) "
                f"the wire {self.muscle} makes the arm swing at {self.omega:.0f} rad/s, and "
                f"MuJoCo's steps must stay well below 2/ω = {2e3 / self.omega:.2g} ms or the "
                f'simulated arm blows up (<option timestep="{self.needed_s:.2g}"/> in the file '
                "makes this its own)")


def timestep(xml: Path, robot, mj: mujoco.MjModel | None = None) -> Timestep:
    """``Timestep`` of the plant MJCF ``xml`` (``mj``: already compiled) driven as ``robot``
    describes."""
    mj = _compile(Path(xml)) if mj is None else mj
    _, tendons, coupled, sweep = _sweep(mj, robot, Path(xml))
    wire = np.array([m.K * (m.f_max + 1.0) for m in robot.muscles])  # N/m at f_max
    springs = np.zeros(mj.ntendon)
    springs[tendons] = wire
    springs += mj.tendon_stiffness
    joint_springs = mj.jnt_stiffness[mj.dof_jntid[coupled.columns]]
    omega2, worst = 0.0, 0
    for pose in sweep:
        stiffness = pose.joints(joint_springs) + pose.jac.T @ (springs[:, None] * pose.jac)
        w, v = scipy.linalg.eigh(stiffness, pose.inertia)
        if w[-1] > omega2:  # the wire doing most of the work in the fastest swing
            omega2 = float(w[-1])
            worst = int(np.argmax(wire * (pose.jac[tendons] @ v[:, -1]) ** 2))
    return Timestep(file_s=float(mj.opt.timestep), omega=float(np.sqrt(max(omega2, 0.0))),
                    muscle=robot.muscles[worst].name, f_max=float(robot.muscles[worst].f_max))


def plant_notes(xml: Path, robot, wait_s: float, calm: bool = True
                ) -> tuple[str, str, dict[str, float]]:
    """Before the plant arm moves: how it rings (``Ringing.note``; '' when it settles within
    ``wait_s``) and the timestep it is integrated with (``Timestep.note``; '' when its file's
    will do), and the joint damping it runs with (``calm``: ``Ringing.calming``, else {}). A
    plant that does not fit the description is refused (``PlantMismatch``)."""
    xml = Path(xml)
    mj = _compile(xml)
    rings = ringing(xml, robot)
    damping = rings.calming(robot.joints, wait_s) if calm else {}
    return (rings.note(xml, robot.joints, wait_s, calmed=calm),
            timestep(xml, robot, mj).note(xml), damping)


def _decay_s(damping: np.ndarray, inertia: np.ndarray) -> float:
    """The slowest 1/e decay time of a motion under ``damping`` and ``inertia``: 2 / the
    smallest eigenvalue of M⁻¹D (inf when some motion is undamped)."""
    rate = float(scipy.linalg.eigh(damping, inertia, eigvals_only=True).min()) / 2
    return np.inf if rate <= 1e-12 else 1.0 / rate


class MujocoPlant:
    """True arm state simulated by MuJoCo; the same interface as ``plant.Plant``."""

    def __init__(self, xml: Path, model, *, speed: float = 1.0, motor_tau_s: float = 0.03,
                 ambient_c: np.ndarray | float = 25.0, heat_at_f_max_c: float = HEAT_AT_F_MAX_C,
                 tau_thermal_s: float = 30.0, settle_s: float = 5.0,
                 joint_damping: Mapping[str, float] | None = None) -> None:
        self.model = model  # the description's ArmModel: muscles, joints, elastic law K
        self.xml = Path(xml)
        self.mj = _compile(self.xml)
        self._map(model.robot)
        # the boards drive the tendons; actuators the MJCF may define are not part of the arm.
        # A blown-up step is detected and reported (``failure``), not silently reset to qpos0.
        self.mj.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ACTUATION
                                        | mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        for name, damping in (joint_damping or {}).items():  # ``Ringing.calming``
            self.mj.dof_damping[self._dof[model.robot.joints.index(name)]] = damping
        self.step_check = timestep(self.xml, model.robot, self.mj)
        self.mj.opt.timestep = self.step_check.step_s
        self.failure: str | None = None  # why the simulation stopped (it then stands still)
        _quiet_mujoco_warnings()
        self.data = mujoco.MjData(self.mj)
        self.speed, self.motor_tau_s, self.tau_thermal_s = speed, motor_tau_s, tau_thermal_s
        m = model.n_muscles
        self.K = np.asarray(model.K, dtype=np.float64)
        self.ambient_c = np.broadcast_to(np.asarray(ambient_c, float), (m,)).copy()
        self.heat_c_per_n = heat_per_newton(model, heat_at_f_max_c)
        self.heat_rate_c_per_s = np.zeros(m)  # injected heating (overheat fault)
        self._J = np.zeros((self.mj.ntendon, self.mj.nv))
        self._home = False
        self._reset_locked()
        # the description's lengths count from theta = 0 (h_geom(0) = 0), not from the
        # file's reference pose qpos0 (a joint's ref), where MjData starts
        self.data.qpos[self._qadr] = 0.0
        self._coupled.place(self.data.qpos)  # followers where their couplings hold
        mujoco.mj_fwdPosition(self.mj, self.data)
        self._h0 = self.data.ten_length[self._tendon].copy()  # tendon lengths at theta = 0
        # power-up: motors hold their length, the arm sags onto its elastic elements
        theta, lengths = power_up(model)
        self.data.qpos[self._qadr] = theta
        self._coupled.place(self.data.qpos)  # and their followers where the couplings hold
        self._is_length = np.ones(m, dtype=bool)
        self._command = lengths.copy()
        self._motor = lengths.copy()  # motor length (m) of length-mode muscles
        self._force = np.zeros(m)  # tension (N) of tension-mode muscles' force loop
        self._tension = np.zeros(m)
        self._gains()
        self._locked = bool(len(self._locked_q) or len(self._locked_v))
        self._lock = threading.Lock()
        self._debt = 0.0  # arm time not yet simulated (less than one timestep)
        self._rest_s = 0.0  # arm time the joints have been slow for
        self._play = FrictionPlay(m)
        self._advance(settle_s, until_rest=True)
        self.state = PlantState(self._theta(), self._tension.copy(), self._length(),
                                self.ambient_c.copy(), np.zeros(m))
        self._play.update(self.state.length)

    def _map(self, robot) -> None:
        """Plant joints and tendons by the description's names; a clear line if missing."""
        jid, self._tendon = _driven(self.mj, robot, self.xml)
        self._qadr, self._dof = self.mj.jnt_qposadr[jid], self.mj.jnt_dofadr[jid]
        self._coupled = _coupled(self.mj, robot, self.xml)
        joints = joint_names(self.mj)
        self._q0 = self.mj.qpos0.copy()
        for name, value in robot.locked:
            if name in joints:
                self._q0[self.mj.jnt_qposadr[joints.index(name)]] = value
        # MuJoCo's equality constraint moves the followers: they are neither driven nor held
        followers = [joints.index(c.follower) for c in self._coupled.couplings]
        driven_q = set(self._qadr.tolist()) | set(self.mj.jnt_qposadr[followers].tolist())
        driven_v = set(self._coupled.columns.tolist())
        self._locked_q = np.array([q for q in range(self.mj.nq) if q not in driven_q], int)
        self._locked_v = np.array([v for v in range(self.mj.nv) if v not in driven_v], int)

    # ------------------------------------------------------------------- the simulation
    def _reset_locked(self) -> None:
        """Joints the description does not drive are held rigid at their locked value."""
        d = self.data
        if len(self._locked_q):
            d.qpos[self._locked_q] = self._q0[self._locked_q]
        if len(self._locked_v):
            d.qvel[self._locked_v] = 0.0
        if self._home:
            d.qpos[self._qadr] = 0.0
            self._coupled.place(d.qpos)
            d.qvel[self._coupled.columns] = 0.0

    def _substep(self) -> None:
        """One MuJoCo timestep: motors, elastic elements, tendon forces, integration (lean:
        thousands of these run per second of arm time)."""
        m, d = self.mj, self.data
        self._motor += self._gain_length * (self._command - self._motor)
        self._force += self._gain_tension * (self._command - self._force)
        mujoco.mj_step1(m, d)
        kdn = self.K * (d.ten_length[self._tendon] - self._h0 - self._motor)
        np.clip(kdn, 0.0, _EXP_CAP, out=kdn)
        self._tension = np.where(self._is_length, np.expm1(kdn), np.maximum(self._force, 0.0))
        mujoco.mju_sparse2dense(self._J, d.ten_J, m.ten_J_rownnz, m.ten_J_rowadr,
                                m.ten_J_colind)
        d.qfrc_applied[:] = self._tension @ self._J[self._tendon]
        d.qfrc_applied *= -1.0
        mujoco.mj_step2(m, d)
        if self._locked:
            self._reset_locked()
        self._rest_s = self._rest_s + m.opt.timestep if self._slow() else 0.0

    def _gains(self) -> None:
        """Per-step first-order gains of the length servos and the tension loops."""
        a = 1.0 - np.exp(-self.mj.opt.timestep / self.motor_tau_s)
        self._gain_length = a * self._is_length
        self._gain_tension = a * ~self._is_length

    def _blew_up(self, peak: np.ndarray) -> bool:
        """The integration has left the arm's physics: MuJoCo's own verdict (a non-finite or
        huge acceleration, position or velocity), a joint spinning faster than any arm
        (``MAX_SPEED``), or a swing the timestep cannot follow (ω·dt ≥ 2 at the tensions
        ``peak`` reached: each step then amplifies it)."""
        bad = (mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADQPOS,
               mujoco.mjtWarning.mjWARN_BADQVEL)
        d = self.data
        if any(d.warning[int(w)].number for w in bad) or not (
                np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()):
            return True
        if np.abs(d.qvel[self._coupled.columns]).max(initial=0.0) > MAX_SPEED:
            return True
        return self._swing(peak) * self.mj.opt.timestep >= 2.0

    def _swing(self, tension: np.ndarray) -> float:
        """rad/s of the fastest swing of the driven joints (their followers moving with them)
        with the wires at ``tension``."""
        m = self.mj
        pose = _reduce(m, self.data, self._coupled, self._J)
        jac = pose.jac[self._tendon]
        load = np.minimum(np.where(np.isfinite(tension), tension, np.inf), np.expm1(_EXP_CAP))
        stiffness = jac.T @ ((self.K * (load + 1.0))[:, None] * jac) + pose.joints(
            m.jnt_stiffness[m.dof_jntid[self._coupled.columns]])
        if not np.isfinite(stiffness).all():
            return np.inf
        w = scipy.linalg.eigh(stiffness, pose.inertia, eigvals_only=True)
        return float(np.sqrt(max(w[-1], 0.0)))

    def _unstable(self, tension: np.ndarray) -> str:
        """The line that says the simulated arm went unstable, and why: the swing its stiffest
        wire drove (at ``tension``, the highest on the way) was too fast for the timestep."""
        m, d = self.mj, self.data
        omega = self._swing(tension)
        k = int(np.argmax(np.where(np.isfinite(tension), tension, np.inf)))
        name = self.model.muscles[k]
        pulled = f"{tension[k]:.0f} N" if np.isfinite(tension[k]) else "no finite tension"
        return (f"the simulated arm ({self.xml}, integrated by MuJoCo) went unstable after "
                f"{d.time:.2f} s of arm time: with the wire {name} at {pulled} it swings at "
                f"{omega:.0f} rad/s, and a {m.opt.timestep * 1e3:.3g} ms step needs that below "
                f"{2.0 / m.opt.timestep:.0f} rad/s. Nothing on the arm failed: give the plant a "
                "smaller <option timestep> (or, if the plan asked for this tension, a wire with "
                "a higher f_max)")

    def _advance(self, arm_s: float, until_rest: bool = False) -> None:
        """Simulate ``arm_s`` seconds of arm time (or until the arm is at rest). Steps that
        blow up are undone back to the start of this call, and the simulation stops there
        with ``failure`` set (it stands still from then on)."""
        if self.failure is not None:
            return
        dt = self.mj.opt.timestep
        self._debt += arm_s
        n = int(self._debt / dt)
        self._debt -= n * dt
        d = self.data
        before = (d.time, d.qpos.copy(), d.qvel.copy(), self._motor.copy(),
                  self._force.copy(), self._tension.copy(), self._rest_s)
        peak = np.zeros_like(self._tension)  # the tensions on the way, for the report
        _QUIET.on = True
        try:
            for _ in range(n):
                self._substep()
                np.fmax(peak, self._tension, out=peak)
                if until_rest and self._at_rest():
                    self._debt = 0.0
                    break
        finally:
            _QUIET.on = False
        if self._blew_up(peak):
            (d.time, d.qpos[:], d.qvel[:], self._motor[:], self._force[:], self._tension[:],
             self._rest_s) = before
            mujoco.mj_forward(self.mj, d)
            self.failure = self._unstable(peak)

    def _slow(self) -> bool:
        return bool(np.abs(self.data.qvel[self._dof]).max(initial=0.0) < SETTLED_SPEED)

    def _at_rest(self) -> bool:
        """Joints slow for the last ``REST_S`` of arm time."""
        return self._rest_s >= REST_S

    def _theta(self) -> np.ndarray:
        return np.array(self.data.qpos[self._qadr])

    def _length(self) -> np.ndarray:
        """Motor lengths: the servo's position, or what a tension loop wound to (h − Δn)."""
        h = self.data.ten_length[self._tendon] - self._h0
        stretch = np.log1p(np.maximum(self._tension, 0.0)) / self.K
        return np.where(self._is_length, self._motor, h - stretch)

    # ------------------------------------------------------------ the Plant interface
    def command(self, modes: tuple[str, ...], values: np.ndarray) -> None:
        """New motor targets (per muscle "length" [m] or "tension" [N])."""
        with self._lock:
            is_length = np.array([mode == "length" for mode in modes])
            # a muscle switching mode starts from where it is (no jump)
            became_length = is_length & ~self._is_length
            self._motor[became_length] = self._length()[became_length]
            became_tension = ~is_length & self._is_length
            self._force[became_tension] = self._tension[became_tension]
            self._is_length = is_length
            self._command = np.array(values, dtype=np.float64)
            self._gains()

    def hold_home(self, on: bool = True) -> None:
        """Hold (or let go of) the arm at its home pose, as a person zeroing it would."""
        with self._lock:
            self._home = on
            self._locked = bool(on or len(self._locked_q) or len(self._locked_v))
            self._reset_locked()

    def at_rest(self) -> None:
        """Unknown to the host, as on a real arm: it judges rest from the readings."""
        return None

    def settled(self, tol: float = 1e-4) -> bool:
        """Joints at rest and every motor within ``tol`` (m) or 0.05 N of its target."""
        with self._lock:
            motor_ok = np.where(self._is_length, np.abs(self._motor - self._command) < tol,
                                np.abs(self._force - self._command) < 0.05)
            return bool(motor_ok.all()) and self._at_rest()

    def step(self, dt: float) -> PlantState:
        """Advance ``dt`` seconds of wall time (× ``speed`` of arm time)."""
        with self._lock:
            dt_arm = dt * self.speed
            self._advance(dt_arm)
            s = self.state
            length = self._length()
            temperature = thermal_step(s.temperature, s.tension, self.ambient_c,
                                       self.heat_c_per_n, self.heat_rate_c_per_s,
                                       dt_arm, dt, self.tau_thermal_s)
            self.state = replace(s, theta=self._theta(), tension=self._tension.copy(),
                                 length=length, temperature=temperature,
                                 approach=self._play.update(length))
            return self.state

    def close(self) -> None:
        """Nothing runs in the background."""
