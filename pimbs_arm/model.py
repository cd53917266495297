"""The shared arm model: muscle geometry, gravity, elasticity, tension QP and static equilibrium.

One implementation serves simulation (``simulate.py``), the mock bus (``pimbs_hw.mock``),
collection and learning, so all of them agree on the physics and its sign conventions
(see docs/design.md): muscles produce joint torque ``-G^T f``, ``gravity_torque`` is the torque
the muscles must supply, and the motor length is ``l = h_geom(theta) - dn(f)``.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import quadprog

from pimbs_arm.backend import ArmBackend, Skeleton, WirePath
from pimbs_arm.backends.viapoints import ViaPointBackend
from pimbs_arm.equilibrium import Equilibrium, solve_equilibrium
from pimbs_calibration.description import RobotDescription, load_robot


class InfeasiblePoseError(RuntimeError):
    """No non-negative tensions above the floor can hold the arm in the requested pose."""


def sample_poses(joint_range: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Draw ``n`` poses uniformly from ``joint_range`` (N, 2); returns (n, N)."""
    joint_range = np.asarray(joint_range, dtype=np.float64)
    return rng.uniform(joint_range[:, 0], joint_range[:, 1], size=(n, len(joint_range)))


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


def make_backend(robot: RobotDescription) -> ArmBackend:
    """The geometry/gravity backend a description asks for: MuJoCo for an MJCF, else
    pinocchio + via points."""
    if robot.mjcf_path is not None:
        from pimbs_arm.backends.mujoco_tendons import MujocoBackend

        return MujocoBackend(robot)
    return ViaPointBackend(robot)


class ArmModel:
    """Muscle + rigid-body model of one robot description (numpy float64 throughout).

    Geometry and gravity come from a backend (``pimbs_arm.backend``); elasticity, the tension QP
    and the equilibrium are computed here, the same for every backend.
    """

    def __init__(self, robot: RobotDescription, backend: ArmBackend | None = None, *,
                 check: bool = True) -> None:
        self.robot = robot
        self.joints = robot.joints
        self.muscles = tuple(m.name for m in robot.muscles)
        self.n_joints = len(robot.joints)
        self.n_muscles = len(robot.muscles)
        self.joint_range = robot.joint_range.copy()
        self.K = np.array([m.K for m in robot.muscles], dtype=np.float64)
        self.f_max = np.array([m.f_max for m in robot.muscles], dtype=np.float64)
        self.backend = make_backend(robot) if backend is None else backend
        self.joint_limits = self.backend.joint_limits
        self._h0 = self.backend.kinematics(np.zeros(self.n_joints), jacobian=False).length
        if check:  # `pimbs robot` explains a description that fails it (check=False)
            from pimbs_arm.routing import check_both_ways  # needs a built model

            check_both_ways(self)

    @classmethod
    def load(cls, name_or_path: str | Path) -> ArmModel:
        """Model of a built-in robot name, a ``.muscles.yaml`` or an MJCF ``.xml`` path."""
        return cls(load_robot(name_or_path))

    def with_backend(self, backend: ArmBackend) -> ArmModel:
        """A copy of this model on another backend (e.g. a 'true' arm whose masses or via
        points differ); the length reference h(0) is re-measured on the new geometry."""
        other = copy.copy(self)
        other.backend = backend
        other._h0 = backend.kinematics(np.zeros(self.n_joints), jacobian=False).length
        return other

    @property
    def _model(self):
        """The pinocchio model of a URDF robot (kept for callers that need pinocchio)."""
        return self.backend._model

    def wire_paths(self, theta) -> list[WirePath]:
        """Each muscle's path at a pose (branches, attachments; m), for pictures."""
        return self.backend.wire_paths(np.asarray(theta, dtype=np.float64))

    def skeleton(self, theta) -> Skeleton:
        """The arm's bones and driven-joint anchors at a pose (m), for pictures."""
        return self.backend.skeleton(np.asarray(theta, dtype=np.float64))

    def link_frames(self, theta) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """World (rotation (3, 3), position (3,)) of every link frame at a pose."""
        return self.backend.link_frames(np.asarray(theta, dtype=np.float64))

    def _length_jacobian(self, theta: np.ndarray, jacobian: bool = True
                         ) -> tuple[np.ndarray, np.ndarray | None]:
        """Absolute path lengths (M,) and, optionally, their Jacobian (M, N)."""
        k = self.backend.kinematics(np.asarray(theta, dtype=np.float64), jacobian)
        return k.length, k.jacobian

    # ----------------------------------------------------------------- geometry and gravity
    def h_geom(self, theta) -> np.ndarray:
        """Geometric muscle length relative to theta = 0: (M,) or (B, M); h_geom(0) = 0."""
        return _batched(lambda t: self._length_jacobian(t, jacobian=False)[0] - self._h0,
                        theta, self.n_joints)

    def muscle_jacobian(self, theta) -> np.ndarray:
        """G = dh_geom/dtheta (analytic, or MuJoCo's ten_J): (M, N) or (B, M, N)."""
        return _batched(lambda t: self._length_jacobian(t)[1], theta, self.n_joints)

    def gravity_torque(self, theta) -> np.ndarray:
        """Pinocchio's generalized gravity g(theta): the torque the muscles must supply."""
        return _batched(self._gravity, theta, self.n_joints)

    def _gravity(self, theta: np.ndarray) -> np.ndarray:
        return self.backend.gravity(np.asarray(theta, dtype=np.float64))

    def inertia(self, theta) -> np.ndarray:
        """(N, N) joint-space inertia of a single pose (armature included): with the held
        wires' stiffness, how fast the arm swings."""
        return self.backend.inertia(np.asarray(theta, dtype=np.float64))

    def potential_energy(self, theta) -> float:
        """Gravity potential energy (J) of a single pose; its gradient is ``gravity_torque``."""
        return self.backend.potential_energy(np.asarray(theta, dtype=np.float64))

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
        return solve_equilibrium(self, mode, command, theta0)
