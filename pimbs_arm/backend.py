"""The seam between ``ArmModel`` and whatever computes an arm's geometry and gravity.

``ArmModel`` owns what is the same for every arm (elasticity, the tension QP, static
equilibrium); a backend owns what depends on how the arm is described: muscle path lengths
and their Jacobians, gravity, and what a picture draws (``WirePath``, ``Skeleton``: computed
by the same kinematics, so the picture shows the arm the numbers describe). Backends live in
``pimbs_arm/backends/``: ``viapoints`` (a URDF through pinocchio plus straight wire segments
between via points) and, for an MJCF, ``mujoco_tendons`` (spatial tendons measured by MuJoCo
itself, wrapping included).

Shapes (N driven joints, M muscles), SI units, numpy float64:
    theta (N,) rad; lengths (M,) m ABSOLUTE (``ArmModel`` subtracts the length at theta = 0);
    jacobian (M, N) = d length / d theta; gravity (N,) N·m, the torque the muscles must supply
    (pinocchio's g(theta), MuJoCo's qfrc_bias at zero velocity), so at rest ``-Gᵀf = g``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np


@dataclass
class Kinematics:
    """Muscle geometry at one pose. ``cache`` is backend-private data that
    ``length_hessian`` may reuse (the equilibrium solver asks for both at the same pose)."""

    length: np.ndarray  # (M,) absolute path lengths, m
    jacobian: np.ndarray | None  # (M, N) d length / d theta, or None if not asked for
    cache: Any = None


@dataclass
class WirePath:
    """One muscle's path at a pose, as a picture draws it (world coordinates, m).

    A pulley divides a tendon into branches that share no segment, so the path is a list of
    polylines; a branch that wraps a sphere or cylinder follows the surface between its two
    tangent points. ``attachments`` are the points the wire is fixed at or runs through
    (sites, via points), marked on the picture."""

    branches: list[np.ndarray]  # (k, 3) each, in path order
    attachments: np.ndarray  # (a, 3)

    @property
    def end(self) -> np.ndarray:
        """Where the wire ends (its insertion): the last point of its last branch."""
        return self.branches[-1][-1]


@dataclass
class Skeleton:
    """The arm's bones at one pose, as a picture draws them (world coordinates, m).

    ``joints`` are where the driven joints sit (their anchors, as the kinematics computes
    them, not the frames of the links they move: an MJCF joint may sit away from its body's
    frame); ``focus`` are the points a view should frame: the moving part of the arm, not a
    floor or a whole body it hangs from."""

    bones: list[tuple[np.ndarray, np.ndarray]]  # (start (3,), end (3,)) segments
    joints: dict[str, np.ndarray]  # driven joint name -> anchor (3,)
    focus: np.ndarray  # (k, 3)


@runtime_checkable
class ArmBackend(Protocol):
    """What ``ArmModel`` needs from an arm description (single poses; ArmModel batches)."""

    joint_limits: np.ndarray  # (N, 2) hard limits of the driven joints (rad)
    kind: str  # "urdf" or "mjcf": for messages saying what a command supports

    def kinematics(self, theta: np.ndarray, jacobian: bool = True) -> Kinematics:
        """Absolute muscle lengths (M,) and, if asked, their Jacobian (M, N)."""
        ...

    def length_hessian(self, theta: np.ndarray, weight: np.ndarray,
                       cache: Any = None) -> np.ndarray:
        """sum_i weight_i d²length_i/dtheta² (N, N), symmetric; ``cache`` from
        ``kinematics`` at the same theta, or None."""
        ...

    def gravity(self, theta: np.ndarray) -> np.ndarray:
        """(N,) generalized gravity g(theta): the joint torque that holds the arm still."""
        ...

    def gravity_derivative(self, theta: np.ndarray) -> np.ndarray:
        """(N, N) d g / d theta."""
        ...

    def potential_energy(self, theta: np.ndarray) -> float:
        """Gravity potential energy (J); its gradient is ``gravity``."""
        ...

    def inertia(self, theta: np.ndarray) -> np.ndarray:
        """(N, N) joint-space inertia of the driven joints (through their couplings), with
        the joints' armature where the description gives it: how fast the arm swings."""
        ...

    def moving_mass(self) -> float:
        """Mass (kg) moved by the driven joints (for the description's explanation)."""
        ...

    def wire_paths(self, theta: np.ndarray) -> list[WirePath]:
        """Each muscle's path at a pose, branches and attachments (for pictures)."""
        ...

    def skeleton(self, theta: np.ndarray) -> Skeleton:
        """The bones and driven-joint anchors at a pose (for pictures)."""
        ...

    def link_frames(self, theta: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """World (rotation (3, 3), position (3,)) of every link / body frame (to check the
        kinematics against another tool's)."""
        ...
