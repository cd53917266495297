"""Static forward problem: the pose an arm settles into under muscle length/tension commands.

The arm settles where gravity potential + elastic potentials (+ f_cmd * h_geom for
tension-controlled muscles, whose motor keeps the tension constant) is minimal within the URDF
limits. With K = 1000 the elastic terms are exponentially stiff, so a first-order method
crawls; we use projected Newton with the exact Hessian (elastic stiffness, the backend's
gravity derivative, tension times wire-path curvature) made positive definite, and a
backtracking line search on the energy. Warm-started from the previous pose it converges in a
few steps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from pimbs_arm.model import ArmModel

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


_EXP_CAP = 60.0  # cap K*dn so far-off trial points give a huge but finite energy
TENSION_SCALE_CAP = 10.0  # of f_max: the largest tension the convergence tolerance scales with


@dataclass
class _State:
    """Everything known at one trial pose: energy, gradient and what the Hessian reuses."""

    theta: np.ndarray
    energy: float
    grad: np.ndarray  # g + G^T f
    g: np.ndarray
    G: np.ndarray
    f: np.ndarray
    h: np.ndarray
    dn: np.ndarray
    paths: object


class _Problem:
    """Energy, gradient and Hessian of one equilibrium problem (fixed commands)."""

    def __init__(self, arm: ArmModel, is_length: np.ndarray, command: np.ndarray) -> None:
        self.arm, self.is_length, self.command = arm, is_length, command
        self.K = arm.K

    def tension(self, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tensions (M,) and stretch (M,) at geometric length h; tension muscles keep f_cmd."""
        dn = np.where(self.is_length, h - self.command, 0.0)
        kdn = np.minimum(self.K * np.maximum(dn, 0.0), _EXP_CAP)
        return np.where(self.is_length, np.expm1(kdn), self.command), dn

    def evaluate(self, theta: np.ndarray) -> _State:
        """Energy and gradient in one kinematics pass (line-search trials are usually kept)."""
        arm = self.arm
        kin = arm.backend.kinematics(theta)
        h = kin.length - arm._h0
        f, dn = self.tension(h)
        # P(dn) = expm1(K dn)/K - dn for dn > 0: its derivative is the tension f.
        elastic = np.where(self.is_length & (dn > 0), f / self.K - np.maximum(dn, 0.0), 0.0)
        held = np.where(self.is_length, 0.0, self.command * h)
        energy = arm.potential_energy(theta) + float(elastic.sum() + held.sum())
        G = kin.jacobian
        g = arm._gravity(theta)
        return _State(theta, energy, g + G.T @ f, g, G, f, h, dn, kin.cache)

    def hessian(self, s: _State) -> np.ndarray:
        """dg/dtheta + G^T diag(K (f + 1)) G (stretched springs) + sum_i f_i d2h_i."""
        stiff = np.where(self.is_length & (s.dn > 0), self.K * (s.f + 1.0), 0.0)
        H = self.arm.backend.gravity_derivative(s.theta) + s.G.T @ (stiff[:, None] * s.G)
        H += self.arm.backend.length_hessian(s.theta, s.f, s.paths)
        return 0.5 * (H + H.T)


def _mode_mask(mode, n_muscles: int) -> np.ndarray:
    modes = np.broadcast_to(np.asarray(mode), (n_muscles,))
    bad = sorted(set(modes.tolist()) - {"length", "tension"})
    if bad:
        raise ValueError(f"mode must be 'length' or 'tension' per muscle, got {bad}")
    return modes == "length"


def _geometric_start(problem: _Problem, theta: np.ndarray, lo, hi) -> np.ndarray:
    """Cold start: damped Gauss-Newton fit of h_geom to the commanded lengths.

    At equilibrium the stretches are millimetres, so this lands where the exponential
    springs are mild and Newton on the energy converges quickly.
    """
    sel = problem.is_length
    if not sel.any():
        return theta
    for _ in range(8):
        h, G = problem.arm._length_jacobian(theta)
        r = (h - problem.arm._h0 - problem.command)[sel]
        J = G[sel]
        step = -np.linalg.solve(J.T @ J + 1e-6 * np.eye(len(theta)), J.T @ r)
        theta = np.clip(theta + step, lo, hi)
        if np.linalg.norm(step) < 1e-9:
            break
    return theta


KINK_PROBE = 1e-6  # rad: how far each joint is moved to see the energy rise at a kink


def _kink_minimum(problem: _Problem, state, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Whether the energy rises whichever way any free joint moves, and down the gradient:
    a rest position at a kink of the energy, where its gradient never vanishes.

    The energy is not smooth everywhere: where a wire passes through its joint's axis (two
    of its via points meet) its length has a corner in the joint angle, its moment arm
    flipping sign. A pose resting on such a corner is an equilibrium (zero lies between the
    one-sided torques), yet Newton stalls there with a residual of newton-metres: on the
    acme arm's elbow, where the flexor's and the biceps' moment arms flip between −29 and
    +29 mm, the one-sided torques were −8.1 and +0.56 N·m, and a collection stopped there
    as if the arm had no rest position. Probed both ways by ``KINK_PROBE``."""
    theta, e0 = state.theta, state.energy
    tol = 1e-12 * (1.0 + abs(e0))
    norm = np.linalg.norm(state.grad)
    moves = [d * axis for axis in np.eye(len(theta)) for d in (-KINK_PROBE, KINK_PROBE)]
    if norm > 0:
        moves.append(-KINK_PROBE * state.grad / norm)
    for move in moves:
        trial = np.clip(theta + move, lo, hi)
        if not np.array_equal(trial, theta) and problem.evaluate(trial).energy < e0 - tol:
            return False
    return True


def solve_equilibrium(arm: ArmModel, mode, command, theta0=None, *, max_iter: int = 100,
                      atol: float = 1e-9) -> Equilibrium:
    """Projected-Newton minimisation of the static energy; see ``ArmModel.equilibrium``."""
    is_length = _mode_mask(mode, arm.n_muscles)
    command = np.asarray(command, dtype=np.float64)
    if command.shape != (arm.n_muscles,) or not np.all(np.isfinite(command)):
        raise ValueError(f"command must be {arm.n_muscles} finite values, got {command!r}")
    lo, hi = arm.joint_limits[:, 0], arm.joint_limits[:, 1]
    problem = _Problem(arm, is_length, command)
    if theta0 is None:
        theta = _geometric_start(problem, np.clip(np.zeros(arm.n_joints), lo, hi), lo, hi)
    else:
        theta = np.clip(np.asarray(theta0, dtype=np.float64), lo, hi)

    converged = False
    state = problem.evaluate(theta)
    for _ in range(max_iter):
        theta, grad = state.theta, state.grad
        free = ~(((theta <= lo) & (grad > 0)) | ((theta >= hi) & (grad < 0)))
        # the torques' own size sets the tolerance, but no more than wires at ten times
        # their f_max carry: a wire at 1e15 N (a joint pulled into its limit) must not make
        # a residual of hundreds of N·m count as converged
        scale = np.linalg.norm(state.g) + np.abs(state.G).T @ np.minimum(
            np.abs(state.f), TENSION_SCALE_CAP * arm.f_max)
        if np.linalg.norm(grad[free]) <= atol + 1e-11 * np.max(scale):
            converged = True
            break
        H = problem.hessian(state)[np.ix_(free, free)]
        w, V = np.linalg.eigh(H)
        w = np.maximum(np.abs(w), 1e-9 * max(np.abs(w).max(), 1e-9))  # saddle-free Newton
        step = np.zeros_like(theta)
        step[free] = -V @ ((V.T @ grad[free]) / w)
        alpha = 1.0
        while True:
            trial = problem.evaluate(np.clip(theta + alpha * step, lo, hi))
            # Armijo, or (near the optimum) a change lost in floating-point noise.
            if (trial.energy <= state.energy + 1e-4 * grad @ (trial.theta - theta)
                    or abs(trial.energy - state.energy) <= 1e-13 * (1.0 + abs(state.energy))):
                break
            alpha *= 0.5
            if alpha < 1e-10:
                break
        if np.array_equal(trial.theta, theta):
            break
        state = trial

    # a corner of the energy, with every wire within what it can carry (wires at 1e15 N
    # against a joint limit are a minimum too, and no result)
    if (not converged and np.all(np.abs(state.f) <= TENSION_SCALE_CAP * arm.f_max)
            and _kink_minimum(problem, state, lo, hi)):
        converged = True
    f, h = state.f, state.h
    length = np.where(is_length, command, h - arm.stretch(f))
    return Equilibrium(theta=state.theta, tension=f, length=length, converged=converged,
                       residual=float(np.linalg.norm(state.grad)))
