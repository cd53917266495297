"""MJCF + spatial tendons: muscle geometry and gravity measured by MuJoCo itself.

The arm backend (see ``pimbs_arm.backend``) of a robot described by an MJCF: every muscle is a
spatial tendon, so its length and Jacobian are MuJoCo's ``ten_length`` and ``ten_J`` after
``mj_kinematics`` + ``mj_comPos`` + ``mj_tendon`` (the position stage of ``mj_forward``,
without collision detection), and sphere/cylinder wrapping and pulleys are exactly what
MuJoCo computes, not a re-implementation. Gravity is the bias force MuJoCo stores in
``qfrc_bias`` (``mj_rne`` without acceleration) at zero joint velocity: the torque that holds
the arm still, the same sign as pinocchio's g(theta). What MuJoCo does not provide is taken by
central finite differences of its exact first derivatives: the length Hessian (from ``ten_J``)
and the gravity derivative (from ``qfrc_bias``); the equilibrium solver uses them only to
choose Newton steps, its stopping test is on the exact gradient.

Joints that are not driven stay at their locked value (the description's ``locked``, default
``qpos0``); ball and free joints stay at ``qpos0``. A joint that an ``<equality><joint>``
couples to a driven one (the description's ``couplings``) is placed where the equality puts
it, exactly, before MuJoCo runs: lengths and gravity are those of the coupled model, and the
Jacobian and gravity with respect to the driven joints run through the coupling by the chain
rule, ``G = ten_J · S`` and ``g = Sᵀ qfrc_bias`` with ``S`` = d(every moved joint)/d(driven
joints) (the quartic's slope along each chain of leaders).
"""

from __future__ import annotations

import copy
import threading

import mujoco
import numpy as np

from pimbs_arm.backend import Kinematics, Skeleton, WirePath
from pimbs_calibration.coupling import CoupledJoints
from pimbs_calibration.description import RobotDescription
from pimbs_calibration.mjcf import compile_model, joint_names, tendon_names
from pimbs_calibration.urdf_model import UNLIMITED

_FD_STEP = 1e-6  # rad: central differences of ten_J / qfrc_bias (error ~ step² and 1e-10)
_PULLEY = -2  # wrap_obj of a pulley entry in MuJoCo's wrap list (it has no point)
_SITE = -1  # wrap_obj of a site (a geom's tangent points carry the geom's id)


class MujocoBackend:
    """MuJoCo's model of an MJCF description whose spatial tendons are the muscles."""

    kind = "mjcf"

    def __init__(self, robot: RobotDescription, model: mujoco.MjModel | None = None) -> None:
        if robot.mjcf_path is None:
            raise ValueError(f"{robot.muscle_path}: not an MJCF description")
        self.robot = robot
        self.joints = robot.joints
        self.n_joints = len(robot.joints)
        self.n_muscles = len(robot.muscles)
        self.mj_model = compile_model(robot.mjcf_path) if model is None else model
        self._setup()

    def _setup(self) -> None:
        m = self.mj_model
        names = joint_names(m)
        jid = np.array([names.index(j) for j in self.joints], dtype=int)
        self._qadr = m.jnt_qposadr[jid]
        self._dof = m.jnt_dofadr[jid]
        # the driven joints and the followers they move (qpos / dof indices)
        self._coupled = CoupledJoints(
            self.joints, self.robot.couplings,
            {n: int(m.jnt_qposadr[i]) for i, n in enumerate(names)},
            {n: int(m.jnt_dofadr[i]) for i, n in enumerate(names)})
        tendons = tendon_names(m)
        self._tendon = np.array([tendons.index(mu.name) for mu in self.robot.muscles], dtype=int)
        self._q0 = m.qpos0.copy()
        for name, value in self.robot.locked:
            self._q0[m.jnt_qposadr[names.index(name)]] = value
        limited = m.jnt_limited[jid].astype(bool)
        self.joint_limits = np.where(limited[:, None], m.jnt_range[jid],
                                     np.array([-UNLIMITED, UNLIMITED]))
        self._data = mujoco.MjData(m)
        # MuJoCo writes its results into _data: serialise users (the mock bus solves in a
        # thread while other threads may query the same model).
        self._lock = threading.Lock()

    def __getstate__(self) -> dict:
        """Pickle support (worker processes): the scratch data and the lock are rebuilt."""
        state = self.__dict__.copy()
        del state["_lock"], state["_data"]
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._data = mujoco.MjData(self.mj_model)
        self._lock = threading.Lock()

    def fresh(self, model: mujoco.MjModel | None = None) -> MujocoBackend:
        """A copy with its own scratch data and lock, optionally on another compiled model
        (the same MJCF with, e.g., a link mass changed)."""
        other = object.__new__(MujocoBackend)
        other.__setstate__({**self.__getstate__(), "mj_model": model or self.mj_model})
        return other

    def with_body_mass(self, body: str, scale: float) -> MujocoBackend:
        """A copy whose ``body`` (a moving body of the MJCF) weighs ``scale`` times as much,
        same centre of mass (its inertia scaled with it). Raises ``ValueError``."""
        m = self.mj_model
        names = {m.body(b).name: b for b in self.moving_bodies()}
        if body not in names or m.body_mass[names[body]] <= 0:
            raise ValueError(f"'{body}' is not a body with mass that a driven joint moves in "
                             f"{self.robot.mjcf_path.name} (those: "
                             f"{', '.join(n for n, b in names.items() if m.body_mass[b] > 0)})")
        other = copy.deepcopy(m)
        other.body_mass[names[body]] *= scale
        other.body_inertia[names[body]] *= scale
        return self.fresh(other)

    def last_body(self) -> str:
        """The heaviest body the last driven joint carries (the forearm, the hand...)."""
        m = self.mj_model
        joint = joint_names(m).index(self.joints[-1])
        carrier = int(m.jnt_bodyid[joint])
        return m.body(carrier).name or f"body{carrier}"

    def muscle_sites(self) -> np.ndarray:
        """Ids of the sites the muscles' tendons run through, in first-use order."""
        m = self.mj_model
        sites: list[int] = []
        for t in self._tendon:
            for k in range(m.tendon_adr[t], m.tendon_adr[t] + m.tendon_num[t]):
                if int(m.wrap_type[k]) == int(mujoco.mjtWrap.mjWRAP_SITE):
                    if int(m.wrap_objid[k]) not in sites:
                        sites.append(int(m.wrap_objid[k]))
        return np.array(sites, dtype=int)

    def with_site_shifts(self, shifts: np.ndarray) -> MujocoBackend:
        """A copy whose muscle sites (``muscle_sites`` order) sit ``shifts`` (S, 3) metres from
        the model's, in their bodies' frames: a routing the description got wrong."""
        other = copy.deepcopy(self.mj_model)
        other.site_pos[self.muscle_sites()] += np.asarray(shifts, dtype=np.float64)
        return self.fresh(other)

    # ----------------------------------------------------------------------- MuJoCo passes
    def _position(self, theta: np.ndarray) -> mujoco.MjData:
        """Run MuJoCo's position stage at theta, followers where their couplings put them
        (caller holds the lock)."""
        d = self._data
        d.qpos[:] = self._q0
        d.qpos[self._qadr] = theta
        self._coupled.place(d.qpos)
        d.qvel[:] = 0.0
        mujoco.mj_kinematics(self.mj_model, d)
        mujoco.mj_comPos(self.mj_model, d)
        mujoco.mj_tendon(self.mj_model, d)
        return d

    def _ten_j(self, d: mujoco.MjData) -> np.ndarray:
        """``ten_J`` (M, N) of the muscles' tendons with respect to the driven joints (through
        the couplings). MuJoCo stores it sparse (rows of the model's ``ten_J_rowadr``/
        ``rownnz``/``colind``) or, in older releases, dense (ntendon, nv): both are read."""
        m = self.mj_model
        values = np.asarray(d.ten_J).reshape(-1)
        if not hasattr(m, "ten_J_rowadr"):
            dense = values.reshape(m.ntendon, m.nv)
        else:
            dense = np.zeros((m.ntendon, m.nv))
            for t in self._tendon:
                adr, nnz = m.ten_J_rowadr[t], m.ten_J_rownnz[t]
                dense[t, m.ten_J_colind[adr:adr + nnz]] = values[adr:adr + nnz]
        if not self.robot.couplings:
            return dense[np.ix_(self._tendon, self._dof)]
        S = self._coupled.jacobian(d.qpos)
        return dense[np.ix_(self._tendon, self._coupled.columns)] @ S

    def kinematics(self, theta: np.ndarray, jacobian: bool = True) -> Kinematics:
        """MuJoCo's absolute tendon lengths (M,) and, if asked, ``ten_J`` (M, N)."""
        theta = np.asarray(theta, dtype=np.float64)
        with self._lock:
            d = self._position(theta)
            length = np.array(d.ten_length[self._tendon])
            G = self._ten_j(d) if jacobian else None
        return Kinematics(length, G)

    def length_hessian(self, theta: np.ndarray, weight: np.ndarray, cache=None) -> np.ndarray:
        """sum_i weight_i d²length_i/dtheta² (N, N) by central differences of ``ten_J``
        (MuJoCo has no second derivative of its wrapping)."""
        with self._lock:
            H = _central_difference(lambda t: weight @ self._ten_j(self._position(t)), theta)
        return 0.5 * (H + H.T)

    def gravity(self, theta: np.ndarray) -> np.ndarray:
        """MuJoCo's bias force at zero velocity on the driven joints: g(theta)."""
        with self._lock:
            return self._bias(np.asarray(theta, dtype=np.float64))

    def _bias(self, theta: np.ndarray) -> np.ndarray:
        """``qfrc_bias`` with qvel = 0 (gravity only) at theta, on the driven joints (a
        follower's share through its coupling: Sᵀ qfrc_bias, by virtual work)."""
        m, d = self.mj_model, self._position(theta)
        mujoco.mj_comVel(m, d)  # qvel = 0: zero velocities, as mj_fwdVelocity would leave
        mujoco.mj_rne(m, d, 0, d.qfrc_bias)  # what mj_fwdVelocity stores in qfrc_bias
        if not self.robot.couplings:
            return np.array(d.qfrc_bias[self._dof])
        return d.qfrc_bias[self._coupled.columns] @ self._coupled.jacobian(d.qpos)

    def gravity_derivative(self, theta: np.ndarray) -> np.ndarray:
        """d g / d theta (N, N) by central differences of ``qfrc_bias``."""
        with self._lock:
            return _central_difference(self._bias, theta)

    def inertia(self, theta: np.ndarray) -> np.ndarray:
        """MuJoCo's joint-space inertia (``mj_fullM``, armature included) of the driven
        joints, a follower's share through its coupling: SᵀMS."""
        m = self.mj_model
        with self._lock:
            d = self._position(np.asarray(theta, dtype=np.float64))
            mujoco.mj_crb(m, d)
            full = np.zeros((m.nv, m.nv))
            mujoco.mj_fullM(m, d, full)
            if not self.robot.couplings:
                return full[np.ix_(self._dof, self._dof)]
            cols, S = self._coupled.columns, self._coupled.jacobian(d.qpos)
            return S.T @ full[np.ix_(cols, cols)] @ S

    def potential_energy(self, theta: np.ndarray) -> float:
        """-sum_b m_b gravity . com_b (J): its gradient is ``gravity``."""
        m = self.mj_model
        with self._lock:
            d = self._position(np.asarray(theta, dtype=np.float64))
            return float(-(m.body_mass[1:] * (d.xipos[1:] @ m.opt.gravity)).sum())

    def moving_mass(self) -> float:
        """Mass (kg) of the bodies that some driven joint moves."""
        return float(self.mj_model.body_mass[self.moving_bodies()].sum())

    def moving_bodies(self) -> np.ndarray:
        """Ids of the bodies carried by a driven joint or a follower (their subtrees)."""
        m = self.mj_model
        names = joint_names(m)
        moved = [*self.joints, *(c.follower for c in self.robot.couplings)]
        carriers = set(m.jnt_bodyid[[names.index(j) for j in moved]].tolist())
        moving = []
        for b in range(1, m.nbody):
            a = b
            while a > 0 and a not in carriers:
                a = int(m.body_parentid[a])
            if a > 0:
                moving.append(b)
        return np.array(moving, dtype=int)

    # ---------------------------------------------------------------------- for pictures
    def wire_paths(self, theta: np.ndarray) -> list[WirePath]:
        """Each muscle's tendon path as MuJoCo computed it at a pose: its branches (a pulley
        starts a new one; MuJoCo's wrap list marks it with ``wrap_obj`` -2), the surface arc
        between the two tangent points where it wraps a sphere or cylinder, its sites."""
        m = self.mj_model
        with self._lock:
            d = self._position(np.asarray(theta, dtype=np.float64))
            xpos = np.asarray(d.wrap_xpos).reshape(-1, 3).copy()
            obj = np.asarray(d.wrap_obj).reshape(-1).copy()
            geoms = (d.geom_xpos.copy(), d.geom_xmat.reshape(-1, 3, 3).copy())
            adr, num = d.ten_wrapadr.copy(), d.ten_wrapnum.copy()
        paths = []
        for t in self._tendon:
            branches: list[np.ndarray] = []
            points: list[np.ndarray] = []
            k, end = int(adr[t]), int(adr[t] + num[t])
            while k < end:
                if obj[k] == _PULLEY:
                    branches.append(np.array(points))
                    points = []
                elif obj[k] >= 0 and points and k + 1 < end and obj[k + 1] == obj[k]:
                    points += _wrap_arc(m, geoms, int(obj[k]), points[-1], xpos[k], xpos[k + 1])
                    k += 1  # a wrapped geom contributes its two tangent points at once
                else:
                    points.append(xpos[k])
                k += 1
            branches.append(np.array(points))
            sites = xpos[adr[t]:end][obj[adr[t]:end] == _SITE]
            paths.append(WirePath([b for b in branches if len(b)], sites.copy()))
        return paths

    def skeleton(self, theta: np.ndarray) -> Skeleton:
        """The moving part of the body tree at a pose as MuJoCo places it: a bone from where
        each body's parent turns to where it turns (a body's first joint's anchor
        ``xanchor``, else its frame ``xpos``), a body without children drawn on to twice its
        centre of mass (``xipos``); the driven joints at their anchors. Bodies no driven
        joint moves (a trunk, a floor) are left out: their frames may lie anywhere, e.g. a
        whole body's at the feet."""
        m = self.mj_model
        names = joint_names(m)
        with self._lock:
            d = self._position(np.asarray(theta, dtype=np.float64))
            anchor, key, com = d.xanchor.copy(), d.xpos.copy(), d.xipos.copy()
        jointed = np.flatnonzero(m.body_jntnum > 0)
        key[jointed] = anchor[m.body_jntadr[jointed]]
        parent = m.body_parentid
        leaf = np.bincount(parent[1:], minlength=m.nbody) == 0
        bones = []
        for b in sorted(self.moving_bodies().tolist()):
            if parent[b] > 0:
                bones.append((key[parent[b]], key[b]))
            if leaf[b] and m.body_mass[b] > 0:
                bones.append((key[b], 2 * com[b] - key[b]))
        bones = [(a, e) for a, e in bones if np.linalg.norm(e - a) > 1e-9]
        joints = {j: anchor[names.index(j)] for j in self.joints}
        focus = np.array([p for bone in bones for p in bone] + list(joints.values()))
        return Skeleton(bones, joints, focus)

    def link_frames(self, theta: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """World (rotation (3, 3), position (3,)) of every body of the MJCF at a pose."""
        m = self.mj_model
        with self._lock:
            d = self._position(np.asarray(theta, dtype=np.float64))
            return {m.body(b).name or f"body{b}": (d.xmat[b].reshape(3, 3).copy(),
                                                   d.xpos[b].copy())
                    for b in range(1, m.nbody)}


def _wrap_arc(m: mujoco.MjModel, geoms: tuple[np.ndarray, np.ndarray], geom: int,
              before: np.ndarray, t0: np.ndarray, t1: np.ndarray) -> list[np.ndarray]:
    """Points along a tendon's wrap over ``geom`` from tangent point ``t0`` to ``t1``: a great
    circle on a sphere, a helix on a cylinder (MuJoCo wraps in the plane across its axis and
    rises linearly). The wire reaches ``t0`` from ``before`` along the surface's tangent, so
    it goes on round the same way (the long way round where MuJoCo's side site asks it to)."""
    centre, rot = geoms[0][geom], geoms[1][geom]
    kind = int(m.geom_type[geom])
    if kind == int(mujoco.mjtGeom.mjGEOM_SPHERE):
        u, v, heading = t0 - centre, t1 - centre, t0 - before
        normal = np.cross(u, v)
        if np.linalg.norm(normal) < 1e-12 * np.dot(u, u):
            normal = np.cross(u, heading)  # opposite points: the plane of arrival decides
        if np.linalg.norm(normal) == 0:
            return [t0, t1]
        normal /= np.linalg.norm(normal)
        angle = float(np.arctan2(np.dot(np.cross(u, v), normal), np.dot(u, v)))
        if np.dot(np.cross(normal, u), heading) < 0:
            normal, angle = -normal, 2 * np.pi - angle
        steps = _arc_steps(angle)
        radius = np.linspace(np.linalg.norm(u), np.linalg.norm(v), steps)
        unit = u / np.linalg.norm(u)
        return [centre + r * (unit * np.cos(a) + np.cross(normal, unit) * np.sin(a))
                for a, r in zip(np.linspace(0, angle, steps), radius, strict=True)][:-1] + [t1]
    if kind == int(mujoco.mjtGeom.mjGEOM_CYLINDER):
        a, b, heading = rot.T @ (t0 - centre), rot.T @ (t1 - centre), rot.T @ (t0 - before)
        phi0, phi1 = np.arctan2(a[1], a[0]), np.arctan2(b[1], b[0])
        turn = -np.sin(phi0) * heading[0] + np.cos(phi0) * heading[1]  # > 0: anticlockwise
        if abs(turn) < 1e-12:
            sweep = (phi1 - phi0 + np.pi) % (2 * np.pi) - np.pi  # no heading: the short way
        else:
            sweep = (phi1 - phi0) % (2 * np.pi) if turn > 0 else -((phi0 - phi1) % (2 * np.pi))
        s = np.linspace(0, 1, _arc_steps(sweep))
        radius = np.hypot(a[0], a[1]) + s * (np.hypot(b[0], b[1]) - np.hypot(a[0], a[1]))
        local = np.stack([radius * np.cos(phi0 + s * sweep), radius * np.sin(phi0 + s * sweep),
                          a[2] + s * (b[2] - a[2])], axis=1)
        return [*(centre + local[:-1] @ rot.T), t1]
    return [t0, t1]


def _arc_steps(angle: float) -> int:
    """Points on a wrapped arc: one every 5 degrees, at least the two ends."""
    return max(2, int(np.ceil(abs(angle) / np.radians(5))) + 1)


def _central_difference(f, theta: np.ndarray) -> np.ndarray:
    """(len(f(theta)), N): column k is (f(theta + h e_k) - f(theta - h e_k)) / 2h."""
    theta = np.asarray(theta, dtype=np.float64)
    columns = []
    for k in range(len(theta)):
        step = np.zeros(len(theta))
        step[k] = _FD_STEP
        columns.append((f(theta + step) - f(theta - step)) / (2 * _FD_STEP))
    return np.stack(columns, axis=1)
