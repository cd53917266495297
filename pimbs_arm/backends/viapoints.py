"""URDF + via points: muscle geometry by pinocchio kinematics and straight wire segments.

The arm backend (see ``pimbs_arm.backend``) of a robot described by a URDF and a ``.muscles.yaml``:
each muscle is a chain of straight segments between via points fixed on links; lengths,
Jacobians and the Hessian are analytic, gravity is pinocchio's.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from pimbs_arm.backend import Kinematics, Skeleton, WirePath
from pimbs_calibration.description import RobotDescription, reduced_model
from pimbs_calibration.urdf_model import link_centres, parse_joints


@dataclass
class _Paths:
    """Wire geometry at one pose (see ``ViaPointBackend._paths``)."""

    seg_len: np.ndarray  # (S,) all segments
    u: np.ndarray  # (S, 3) unit directions
    jp: np.ndarray | None = None  # (E, 3, N) Jacobians of crossing-segment end points
    omega: np.ndarray | None = None  # (3, N) joint axes in world


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product along axis 1 (broadcasting); np.cross is slow for many small arrays."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=1)


def _directions(d: np.ndarray, seg_len: np.ndarray) -> np.ndarray:
    """(S, 3) unit vectors along the segments ``d`` (S, 3) of lengths ``seg_len``.

    Two via points on different links can meet (a wire through its joint's axis: in the
    ACME fixture the elbow flexor's near an elbow angle of -1.08 rad, inside the URDF's
    limits, which the equilibrium solver may explore). There the segment has length 0 and
    no direction: its length is not differentiable, and the middle of its one-sided
    derivatives, 0, is used (direction 0, no curvature) instead of dividing 0 by 0, which
    would turn the muscle's Jacobian and the solver's Hessian into NaN.
    """
    return np.divide(d, seg_len[:, None], out=np.zeros_like(d), where=seg_len[:, None] > 0)


class ViaPointBackend:
    """Pinocchio model of a URDF description with via-point muscles."""

    kind = "urdf"

    def __init__(self, robot: RobotDescription) -> None:
        self.robot = robot
        self.joints = robot.joints
        self.n_joints = len(robot.joints)
        self.n_muscles = len(robot.muscles)
        reduced = reduced_model(robot)  # joints not driven are locked, mimics follow
        self._model = reduced.model
        self._S, self._offset = reduced.S, reduced.offset  # q = S theta + offset
        self._data = self._model.createData()
        # pinocchio writes its results into _data: serialise users (the mock bus solves in a
        # thread while other threads may query the same model).
        self._lock = threading.Lock()
        self._build_index()
        iq = [self._model.joints[self._model.getJointId(j)].idx_q for j in self.joints]
        self.joint_limits = np.stack([self._model.lowerPositionLimit[iq],
                                      self._model.upperPositionLimit[iq]], axis=1)

    def __getstate__(self) -> dict:
        """Pickle support (e.g. for worker processes): the lock and the scratch data are
        rebuilt on unpickling."""
        state = self.__dict__.copy()
        del state["_lock"], state["_data"]
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._data = self._model.createData()
        self._lock = threading.Lock()

    def fresh(self, model: pin.Model | None = None, via_local: np.ndarray | None = None
              ) -> ViaPointBackend:
        """A copy with its own scratch data and lock, optionally another pinocchio model
        (e.g. a link's mass changed) or other via points (V, 3) in their joint frames."""
        other = object.__new__(ViaPointBackend)
        other.__setstate__({**self.__getstate__(), "_model": model or self._model})
        if via_local is not None:
            other._via_local = np.asarray(via_local, dtype=np.float64)
        return other

    def _build_index(self) -> None:
        """Precompute via points in their parent-joint frames and the segment -> muscle map.

        Internally every joint of the reduced model is a column (the driven joints and the
        mimic joints following them); ``_S`` maps the columns back to driven joints.
        """
        model = self._model
        jids = list(range(1, model.njoints))
        self._iv = np.array([model.joints[j].idx_v for j in jids])
        self._S = self._S[[model.joints[j].idx_q for j in jids]]
        parents, points, owner = [], [], []
        for i, muscle in enumerate(self.robot.muscles):
            for via in muscle.path:
                frame = model.frames[model.getBodyId(via.link)]
                parents.append(frame.parentJoint)
                points.append(frame.placement.act(via.point))
                owner.append(i)
        self._joint_ids = sorted(set(parents))
        self._via_joint = np.array([self._joint_ids.index(p) for p in parents])
        self._via_local = np.array(points, dtype=np.float64)  # (V, 3) in parent-joint frame
        # Which actuated joints move each via point, and which joint is nearer the root.
        self._via_moves = np.array([[j in model.supports[p] for j in jids] for p in parents],
                                   dtype=np.float64)  # (V, N)
        outer = np.array([[a in model.supports[b] for b in jids] for a in jids])  # a <= b
        n = len(jids)
        self._offset = self._offset[[model.joints[j].idx_q for j in jids]]
        self._iq_cols = np.array([model.joints[j].idx_q for j in jids])
        self._pair_inner = np.where(outer, np.arange(n)[:, None], np.arange(n)[None, :])
        self._pair_outer = np.where(outer, np.arange(n)[None, :], np.arange(n)[:, None])
        owner = np.array(owner)
        # Segment k joins via point k and k+1 of the same muscle.
        seg_a = np.flatnonzero(owner[:-1] == owner[1:])
        self._seg_a, self._seg_b = seg_a, seg_a + 1
        self._seg_owner = owner[seg_a]
        self._seg_muscle = np.zeros((self.n_muscles, len(seg_a)))
        self._seg_muscle[owner[seg_a], np.arange(len(seg_a))] = 1.0
        # Segments whose ends ride on different joints: the only ones that change length.
        via_joint = np.array(parents)
        self._moving = np.flatnonzero(via_joint[seg_a] != via_joint[seg_a + 1])
        self._moving_muscle = self._seg_muscle[:, self._moving]
        self._end_points, ends = np.unique(np.concatenate([seg_a[self._moving],
                                                           seg_a[self._moving] + 1]),
                                           return_inverse=True)
        self._moving_a, self._moving_b = np.split(ends, 2)

    def _q(self, theta: np.ndarray) -> np.ndarray:
        q = pin.neutral(self._model)
        q[self._iq_cols] = self._S @ theta + self._offset
        return q

    def _paths(self, theta: np.ndarray, jacobian: bool = True) -> _Paths:
        """Via points, segment lengths/directions and (if asked) point Jacobians at theta.

        One pinocchio pass. A point p carried by revolute joint k moves with
        J_lin[:, k] + omega_k x p, where the WORLD-frame joint Jacobian's linear part is the
        velocity of the point at the origin. Jacobians are kept only for the endpoints of
        segments that cross a joint (the others have constant length). Their columns are the
        reduced model's joints (``_S`` maps them to the driven joints).
        """
        model, data = self._model, self._data
        q = self._q(theta)
        with self._lock:
            if jacobian:
                pin.computeJointJacobians(model, data, q)  # also runs forward kinematics
                # (6, nv) always: pinocchio hands a one-joint model's Jacobian back as (6,)
                J = np.asarray(data.J).reshape(6, -1)[:, self._iv]
            else:
                pin.forwardKinematics(model, data, q)
            p = self._world_points()
        d = p[self._seg_b] - p[self._seg_a]
        seg_len = np.sqrt(np.einsum("si,si->s", d, d))
        paths = _Paths(seg_len=seg_len, u=_directions(d, seg_len))
        if jacobian:
            pe = p[self._end_points]
            paths.omega = J[3:]
            paths.jp = (J[None, :3] + _cross(J[None, 3:], pe[:, :, None])) \
                * self._via_moves[self._end_points][:, None, :]  # (E, 3, N)
        return paths

    def _world_points(self) -> np.ndarray:
        """(V, 3) via points in the world frame, from the kinematics in ``_data``."""
        data = self._data
        rot = np.array([data.oMi[j].rotation for j in self._joint_ids])[self._via_joint]
        trans = np.array([data.oMi[j].translation for j in self._joint_ids])[self._via_joint]
        return np.einsum("vij,vj->vi", rot, self._via_local) + trans

    def wire_paths(self, theta) -> list[WirePath]:
        """Each muscle's wire at a pose: one straight polyline through its via points (m)."""
        theta = np.asarray(theta, dtype=np.float64)
        with self._lock:
            pin.forwardKinematics(self._model, self._data, self._q(theta))
            p = self._world_points()
        counts = [len(m.path) for m in self.robot.muscles]
        return [WirePath([points], points) for points in np.split(p, np.cumsum(counts)[:-1])]

    def skeleton(self, theta) -> Skeleton:
        """The URDF's link tree at a pose: a bone from each parent link's frame to its child's
        (locked joints included), a link without children to twice its centre of mass; each
        driven joint at its child link's frame (where a URDF joint sits). Every link is framed
        in the view."""
        text = self.robot.urdf_path.read_text()
        urdf = parse_joints(self.robot.urdf_path, text)
        centres = link_centres(text)
        frames = self.link_frames(theta)
        parents = {j.parent for j in urdf.values()}
        bones = [(frames[j.parent][1], frames[j.child][1]) for j in urdf.values()
                 if j.parent in frames and j.child in frames]
        bones += [(p, p + 2 * rot @ centres[name]) for name, (rot, p) in frames.items()
                  if name not in parents and name in centres]
        joints = {name: frames[urdf[name].child][1] for name in self.joints}
        focus = np.array([*(p for _, p in frames.values()), *(e for b in bones for e in b)])
        return Skeleton(bones, joints, focus)

    def link_frames(self, theta) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """World (rotation (3, 3), position (3,)) of every link frame of the URDF at a pose."""
        theta = np.asarray(theta, dtype=np.float64)
        with self._lock:
            pin.framesForwardKinematics(self._model, self._data, self._q(theta))
            return {f.name: (np.array(self._data.oMf[k].rotation),
                             np.array(self._data.oMf[k].translation))
                    for k, f in enumerate(self._model.frames)
                    if f.type == pin.FrameType.BODY}

    def kinematics(self, theta: np.ndarray, jacobian: bool = True) -> Kinematics:
        """Absolute path lengths (M,) and, optionally, their analytic Jacobian (M, N)."""
        paths = self._paths(np.asarray(theta, dtype=np.float64), jacobian)
        return Kinematics(self._seg_muscle @ paths.seg_len,
                          self._jacobian(paths) if jacobian else None, paths)

    def _jacobian(self, paths: _Paths) -> np.ndarray:
        """G (M, N): a crossing segment's length changes by u^T (J_b - J_a)."""
        u = paths.u[self._moving]
        dv = paths.jp[self._moving_b] - paths.jp[self._moving_a]
        return self._moving_muscle @ np.einsum("si,sin->sn", u, dv) @ self._S

    def length_hessian(self, theta: np.ndarray, weight: np.ndarray,
                       cache: _Paths | None = None) -> np.ndarray:
        """sum_i weight_i d2h_i/dtheta2 (N, N), analytic.

        The equilibrium solver needs it for the tension-times-path-curvature part of the
        stiffness. For a segment, d2L = (dv^T dv - (u^T dv)^T (u^T dv)) / L + u^T d2(p_b - p_a),
        and for a point moved by joints k (nearer the root) and l: d2p = omega_k x J_l.
        """
        paths = self._paths(theta) if cache is None else cache
        u, seg_len = paths.u[self._moving], paths.seg_len[self._moving]
        dv = paths.jp[self._moving_b] - paths.jp[self._moving_a]  # (S, 3, N)
        udv = np.einsum("si,sin->sn", u, dv)
        w = weight[self._seg_owner[self._moving]]
        curv = np.einsum("sin,sim->snm", dv, dv) - udv[:, :, None] * udv[:, None, :]
        # a segment of zero length has no curvature to add (see ``_directions``)
        bend = np.divide(w, seg_len, out=np.zeros_like(seg_len), where=seg_len > 0)
        H = np.einsum("s,snm->nm", bend, curv)
        # d2p[e, :, k, l] = omega_inner x J_outer, zero unless both joints move the point.
        d2p = _cross(paths.omega[:, self._pair_inner][None], paths.jp[:, :, self._pair_outer])
        moves = self._via_moves[self._end_points]
        d2p = d2p * (moves[:, :, None] * moves[:, None, :])[:, None]
        H += np.einsum("s,si,sinm->nm", w, u, d2p[self._moving_b] - d2p[self._moving_a])
        H = self._S.T @ H @ self._S  # q is linear in theta: no second-order term
        return 0.5 * (H + H.T)

    def gravity(self, theta: np.ndarray) -> np.ndarray:
        """Pinocchio's generalized gravity g(theta) of the driven joints."""
        with self._lock:
            g = pin.computeGeneralizedGravity(self._model, self._data, self._q(theta))
            return self._S.T @ np.array(g)[self._iv]

    def gravity_derivative(self, theta: np.ndarray) -> np.ndarray:
        with self._lock:
            dg = pin.computeGeneralizedGravityDerivatives(self._model, self._data,
                                                          self._q(theta))
            return self._S.T @ np.array(dg)[np.ix_(self._iv, self._iv)] @ self._S

    def inertia(self, theta: np.ndarray) -> np.ndarray:
        """Pinocchio's joint-space inertia (CRBA, the URDF's rotor inertia as armature) of
        the driven joints."""
        with self._lock:
            M = pin.crba(self._model, self._data, self._q(np.asarray(theta, float)))
            M = np.triu(M) + np.triu(M, 1).T  # crba fills the upper triangle
            return self._S.T @ M[np.ix_(self._iv, self._iv)] @ self._S

    def potential_energy(self, theta: np.ndarray) -> float:
        with self._lock:
            return float(pin.computePotentialEnergy(self._model, self._data,
                                                    self._q(np.asarray(theta, float))))

    def moving_mass(self) -> float:
        return float(sum(inertia.mass for inertia in self._model.inertias[1:]))
