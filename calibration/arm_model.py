"""The shared arm model: muscle geometry, gravity, elasticity, tension QP and static equilibrium.

One implementation serves simulation (``simulate.py``), the mock bus (``pimbs_hw.mock``),
collection and learning, so all of them agree on the physics and its sign conventions
(see docs/design.md): muscles produce joint torque ``-G^T f``, ``gravity_torque`` is the torque
the muscles must supply, and the motor length is ``l = h_geom(theta) - dn(f)``.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
import quadprog

from pimbs_calibration.description import RobotDescription, load_robot, reduced_model


class InfeasiblePoseError(RuntimeError):
    """No non-negative tensions above the floor can hold the arm in the requested pose."""


@dataclass
class Equilibrium:
    """Result of ``ArmModel.equilibrium``.

    ``length`` is what each motor encoder reads: the commanded length for length-mode muscles
    (also when slack, where it exceeds the geometric length), ``h_geom - dn(f_cmd)`` for
    tension-mode muscles. ``residual`` is ``||g(theta) + G^T f||``; it is non-zero only where a
    joint rests on its URDF limit.
    """

    theta: np.ndarray  # (N,)
    tension: np.ndarray  # (M,)
    length: np.ndarray  # (M,)
    converged: bool
    residual: float


def sample_poses(joint_range: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Draw ``n`` poses uniformly from ``joint_range`` (N, 2); returns (n, N)."""
    joint_range = np.asarray(joint_range, dtype=np.float64)
    return rng.uniform(joint_range[:, 0], joint_range[:, 1], size=(n, len(joint_range)))


@dataclass
class _Paths:
    """Wire geometry at one pose (see ``ArmModel._paths``)."""

    seg_len: np.ndarray  # (S,) all segments
    u: np.ndarray  # (S, 3) unit directions
    jp: np.ndarray | None = None  # (E, 3, N) Jacobians of crossing-segment end points
    omega: np.ndarray | None = None  # (3, N) joint axes in world


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product along axis 1 (broadcasting); np.cross is slow for many small arrays."""
    a0, a1, a2 = a[:, 0], a[:, 1], a[:, 2]
    b0, b1, b2 = b[:, 0], b[:, 1], b[:, 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=1)


def _batched(fn, theta, n_joints: int) -> np.ndarray:
    """Apply a single-pose function to (N,) or (B, N) input, stacking along the batch axis."""
    theta = np.asarray(theta, dtype=np.float64)
    if theta.shape == (n_joints,):
        return fn(theta)
    if theta.ndim != 2 or theta.shape[1] != n_joints:
        raise ValueError(f"theta must have shape ({n_joints},) or (B, {n_joints}), "
                         f"got {theta.shape}")
    if not len(theta):
        return np.empty((0,) + fn(np.zeros(n_joints)).shape)
    return np.stack([fn(t) for t in theta])


class ArmModel:
    """Rigid-body + muscle model of one robot description (numpy float64 throughout)."""

    def __init__(self, robot: RobotDescription) -> None:
        self.robot = robot
        self.joints = robot.joints
        self.muscles = tuple(m.name for m in robot.muscles)
        self.n_joints = len(robot.joints)
        self.n_muscles = len(robot.muscles)
        self.joint_range = robot.joint_range.copy()
        self.K = np.array([m.K for m in robot.muscles], dtype=np.float64)
        self.f_max = np.array([m.f_max for m in robot.muscles], dtype=np.float64)
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
        self._h0 = self._length_jacobian(np.zeros(self.n_joints), jacobian=False)[0]
        from pimbs_calibration.routing import check_both_ways  # needs a built model

        check_both_ways(self)

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

    @classmethod
    def load(cls, name_or_path: str | Path) -> ArmModel:
        """Model of a built-in robot name or a ``.muscles.yaml`` path."""
        return cls(load_robot(name_or_path))

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
                J = data.J[:, self._iv]
            else:
                pin.forwardKinematics(model, data, q)
            p = self._world_points()
        d = p[self._seg_b] - p[self._seg_a]
        seg_len = np.sqrt(np.einsum("si,si->s", d, d))
        paths = _Paths(seg_len=seg_len, u=d / seg_len[:, None])
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

    def via_points(self, theta) -> list[np.ndarray]:
        """World positions (k_i, 3) of each muscle's via points at one pose (m)."""
        theta = np.asarray(theta, dtype=np.float64)
        with self._lock:
            pin.forwardKinematics(self._model, self._data, self._q(theta))
            p = self._world_points()
        counts = [len(m.path) for m in self.robot.muscles]
        return np.split(p, np.cumsum(counts)[:-1])

    def link_frames(self, theta) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """World (rotation (3, 3), position (3,)) of every link frame of the URDF at a pose."""
        theta = np.asarray(theta, dtype=np.float64)
        with self._lock:
            pin.framesForwardKinematics(self._model, self._data, self._q(theta))
            return {f.name: (np.array(self._data.oMf[k].rotation),
                             np.array(self._data.oMf[k].translation))
                    for k, f in enumerate(self._model.frames)
                    if f.type == pin.FrameType.BODY}

    def _length_jacobian(self, theta: np.ndarray, jacobian: bool = True
                         ) -> tuple[np.ndarray, np.ndarray | None]:
        """Absolute path lengths (M,) and, optionally, their analytic Jacobian (M, N)."""
        paths = self._paths(theta, jacobian)
        return self._seg_muscle @ paths.seg_len, (self._jacobian(paths) if jacobian else None)

    def _jacobian(self, paths: _Paths) -> np.ndarray:
        """G (M, N): a crossing segment's length changes by u^T (J_b - J_a)."""
        u = paths.u[self._moving]
        dv = paths.jp[self._moving_b] - paths.jp[self._moving_a]
        return self._moving_muscle @ np.einsum("si,sin->sn", u, dv) @ self._S

    def _length_hessian(self, theta: np.ndarray, weight: np.ndarray,
                        paths: _Paths | None = None) -> np.ndarray:
        """sum_i weight_i d2h_i/dtheta2 (N, N), analytic.

        The equilibrium solver needs it for the tension-times-path-curvature part of the
        stiffness. For a segment, d2L = (dv^T dv - (u^T dv)^T (u^T dv)) / L + u^T d2(p_b - p_a),
        and for a point moved by joints k (nearer the root) and l: d2p = omega_k x J_l.
        """
        paths = self._paths(theta) if paths is None else paths
        u, seg_len = paths.u[self._moving], paths.seg_len[self._moving]
        dv = paths.jp[self._moving_b] - paths.jp[self._moving_a]  # (S, 3, N)
        udv = np.einsum("si,sin->sn", u, dv)
        w = weight[self._seg_owner[self._moving]]
        curv = np.einsum("sin,sim->snm", dv, dv) - udv[:, :, None] * udv[:, None, :]
        H = np.einsum("s,snm->nm", w / seg_len, curv)
        # d2p[e, :, k, l] = omega_inner x J_outer, zero unless both joints move the point.
        d2p = _cross(paths.omega[:, self._pair_inner][None], paths.jp[:, :, self._pair_outer])
        moves = self._via_moves[self._end_points]
        d2p = d2p * (moves[:, :, None] * moves[:, None, :])[:, None]
        H += np.einsum("s,si,sinm->nm", w, u, d2p[self._moving_b] - d2p[self._moving_a])
        H = self._S.T @ H @ self._S  # q is linear in theta: no second-order term
        return 0.5 * (H + H.T)

    # ----------------------------------------------------------------- geometry and gravity
    def h_geom(self, theta) -> np.ndarray:
        """Geometric muscle length relative to theta = 0: (M,) or (B, M); h_geom(0) = 0."""
        return _batched(lambda t: self._length_jacobian(t, jacobian=False)[0] - self._h0,
                        theta, self.n_joints)

    def muscle_jacobian(self, theta) -> np.ndarray:
        """Analytic G = dh_geom/dtheta: (M, N) or (B, M, N)."""
        return _batched(lambda t: self._length_jacobian(t)[1], theta, self.n_joints)

    def gravity_torque(self, theta) -> np.ndarray:
        """Pinocchio's generalized gravity g(theta): the torque the muscles must supply."""
        return _batched(self._gravity, theta, self.n_joints)

    def _gravity(self, theta: np.ndarray) -> np.ndarray:
        with self._lock:
            g = pin.computeGeneralizedGravity(self._model, self._data, self._q(theta))
            return self._S.T @ np.array(g)[self._iv]

    def _gravity_derivative(self, theta: np.ndarray) -> np.ndarray:
        with self._lock:
            dg = pin.computeGeneralizedGravityDerivatives(self._model, self._data,
                                                          self._q(theta))
            return self._S.T @ np.array(dg)[np.ix_(self._iv, self._iv)] @ self._S

    def potential_energy(self, theta) -> float:
        """Gravity potential energy (J) of a single pose; its gradient is ``gravity_torque``."""
        theta = np.asarray(theta, dtype=np.float64)
        with self._lock:
            return float(pin.computePotentialEnergy(self._model, self._data, self._q(theta)))

    # ------------------------------------------------------------------------- elasticity
    def stretch(self, tension) -> np.ndarray:
        """Stretch dn = log1p(f)/K of the elastic element (m); negative tension reads 0."""
        return np.log1p(np.maximum(np.asarray(tension, dtype=np.float64), 0.0)) / self.K

    def tension_from_stretch(self, dn) -> np.ndarray:
        """Tension f = expm1(K max(dn, 0)): a slack wire (dn <= 0) pulls nothing."""
        return np.expm1(self.K * np.maximum(np.asarray(dn, dtype=np.float64), 0.0))

    def length(self, theta, tension) -> np.ndarray:
        """Motor-encoder length l = h_geom(theta) - dn(f) (physical sign, see design.md)."""
        return self.h_geom(theta) - self.stretch(tension)

    # -------------------------------------------------------------------------- statics
    def tension_distribution(self, theta, f_min, W=None, f_max=None) -> np.ndarray:
        """Minimum-effort tensions holding ``theta``: min f^T W f s.t. -G^T f = g,
        f_min <= f (<= f_max when given).

        Args:
            theta: (N,) or (B, N) pose(s).
            f_min: tension floor, scalar, (M,), or (B, M) for a batch (per-sample scalars:
                pass ``f_min[:, None]``).
            W: (M, M) positive-definite weight, identity if None.
            f_max: (M,) tension ceiling, or None for none.
        Returns:
            (M,) or (B, M) tensions in N.
        Raises:
            InfeasiblePoseError: the muscles cannot hold the pose within the bounds.
        """
        theta = np.asarray(theta, dtype=np.float64)
        weight = np.eye(self.n_muscles) if W is None else np.asarray(W, dtype=np.float64)
        ceiling = None if f_max is None else np.broadcast_to(
            np.asarray(f_max, dtype=np.float64), (self.n_muscles,))
        if theta.ndim == 1:
            floor = np.broadcast_to(np.asarray(f_min, dtype=np.float64), (self.n_muscles,))
            return self._qp(theta, floor, weight, ceiling)
        floor = np.broadcast_to(np.asarray(f_min, dtype=np.float64),
                                (len(theta), self.n_muscles))
        return np.stack([self._qp(t, fl, weight, ceiling)
                         for t, fl in zip(theta, floor, strict=True)])

    def _qp(self, theta: np.ndarray, f_min: np.ndarray, weight: np.ndarray,
            f_max: np.ndarray | None = None) -> np.ndarray:
        G = self._length_jacobian(theta)[1]
        return self.tensions_for(theta, G, f_min, weight, f_max)

    def tensions_for(self, theta: np.ndarray, G: np.ndarray, f_min: np.ndarray,
                     weight: np.ndarray | None = None, f_max: np.ndarray | None = None
                     ) -> np.ndarray:
        """The tension QP of one pose with a given muscle Jacobian G (M, N).

        ``tension_distribution`` passes the geometric G; a learned body schema passes its own
        (the torque balance is the same, the moment arms are the schema's).
        """
        g = self._gravity(theta)
        weight = np.eye(self.n_muscles) if weight is None else weight
        # quadprog: min 1/2 x^T P x - a^T x  s.t.  C^T x >= b, the first meq rows as equalities.
        eye = np.eye(self.n_muscles)
        C = np.hstack([-G, eye] + ([] if f_max is None else [-eye]))
        b = np.concatenate([g, f_min] + ([] if f_max is None else [-f_max]))
        try:
            f = quadprog.solve_qp(2.0 * weight, np.zeros(self.n_muscles), C, b,
                                  meq=self.n_joints)[0]
        except ValueError as exc:
            bound = "" if f_max is None else f" <= {np.round(f_max, 1).tolist()} N"
            pose = dict(zip(self.joints, np.round(theta, 4).tolist(), strict=True))
            raise InfeasiblePoseError(
                f"{self.robot.muscle_path}: no tensions >= {np.round(f_min, 1).tolist()} N"
                f"{bound} hold {pose} "
                f"against gravity {np.round(g, 3).tolist()} N*m ({exc}); the muscles cannot "
                f"hold this pose. Run `pimbs robot {self.robot.muscle_path}` to see which "
                "joint lacks a muscle pulling it one way, or narrow that joint's range"
            ) from exc
        return f

    def equilibrium(self, mode, command, theta0=None) -> Equilibrium:
        """Static pose reached when each muscle is commanded a motor length or a tension.

        Args:
            mode: (M,) of "length" | "tension" (a single string applies to all muscles).
            command: (M,) motor length l_cmd (m) for length mode, tension f_cmd (N) otherwise.
            theta0: (N,) start pose; pass the previous pose for speed (the mock bus does).
        Returns:
            Equilibrium minimising gravity + elastic potential within the URDF limits.
        """
        from pimbs_calibration.statics import solve_equilibrium  # solver lives in its own module

        return solve_equilibrium(self, mode, command, theta0)
