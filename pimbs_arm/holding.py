"""How a pose is held: which muscles hold it in length, the tensions it is approached at, and
whether the arm stays there.

A pose whose torques balance can still be a saddle of the static energy: each wire's tension
times the curvature of its path (wrapping a sphere, a pulley, a path split between joints)
adds to the stiffness, and where it is negative and the held wires' own stiffness does not
outweigh it, the arm runs off the pose the moment it is disturbed. MyoSuite's finger shows
it: at most of its ATL tensions, holding the four most useful of its five tendons in length
leaves the finger a saddle (a negative stiffness of 4 to 9 N·m/rad), and MuJoCo's dynamics
run it off by 0.3 rad and more. The equilibrium solver, started at the pose, sees zero
torque there and reports it converged.

So a holding is chosen, not assumed: the stiffness of the static energy (gravity's
derivative, Σ fᵢ ∂²hᵢ, and K(fᵢ + 1) gᵢgᵢᵀ of every length-held wire) must be positive
definite at the holding and at the start of the slack removal (held wires at the approach,
the others tension-controlled there), and with every wire length-controlled at the approach
tensions (the move). Along the slack removal every tension moves on a straight line between
those two, and the stiffness is affine in the tensions, so its smallest eigenvalue (concave
in the line's parameter) is positive all the way when it is at both ends.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from pimbs_arm.backend import Kinematics
    from pimbs_arm.model import ArmModel

# the stiffness a holding needs: a tension error of TENSION_ERROR_N on the longest moment arm
# moves the pose by at most POSE_ERROR_RAD (a board holds its tension to about 1 N; with less,
# MyoSuite's finger rested 0.3 rad off its approach, in another rest position of its lengths).
# A loadcell's error scales with its range: a muscle weaker than 100 N is held to
# TENSION_ERROR_SHARE of its f_max (MyoSuite's motor finger pulls 5 to 20 N, of which 1 N is a
# fifth: no pose of it would count as held)
TENSION_ERROR_N = 1.0
TENSION_ERROR_SHARE = 0.01
POSE_ERROR_RAD = 0.05
# the approach tensions: the lowest that hold the pose, blended toward the holding's ones by
# these shares until the approach is stable (1: the approach carries the holding's tensions)
APPROACH_BLENDS = (0.0, 0.25, 0.5, 0.75, 1.0)
MAX_CANDIDATE_SETS = 200  # held sets tried beyond the greedy one (large arms: first ones only)


@dataclass(frozen=True)
class Holding:
    """The length-held muscles of a pose and the tensions it is approached at."""

    held: np.ndarray              # (M,) bool: length-controlled while holding
    approach_tension: np.ndarray  # (M,) N, balances the pose; every wire length-held at it
    stiffness: float              # N·m/rad, the smallest eigenvalue over the checked states


def held_muscles(G: np.ndarray, tension: np.ndarray, slack: float = 0.5) -> np.ndarray:
    """Mask of N loaded muscles whose rows of G (M, N) span the joints well.

    Holding load-bearing muscles in length keeps the pose stiff (elastic elements are stiffest
    under load), but only if their moment arms span every joint direction: a nearly singular
    set lets the arm drift along the weak direction. Greedy: each pick is the most loaded of
    the muscles that keep the smallest singular value of the picked rows within ``slack`` of
    the best pick possible.
    """
    n_joints = G.shape[1]
    chosen: list[int] = []
    for k in range(n_joints):
        rest = [m for m in range(len(tension)) if m not in chosen]
        sigma = np.array([np.linalg.svd(G[chosen + [m]], compute_uv=False)[k] for m in rest])
        ok = [m for m, s in zip(rest, sigma, strict=True) if s >= slack * sigma.max()]
        chosen.append(max(ok, key=lambda m: tension[m]))
    mask = np.zeros(len(tension), dtype=bool)
    mask[chosen] = True
    return mask


class _Stiffness:
    """The static stiffness at one pose, for any tensions on the line between two
    (the path curvature Σ fᵢ ∂²hᵢ is linear in f: two curvature evaluations serve all)."""

    def __init__(self, arm: ArmModel, theta: np.ndarray, low: np.ndarray,
                 high: np.ndarray, kin: Kinematics | None = None) -> None:
        backend = arm.backend
        kin = backend.kinematics(theta) if kin is None else kin
        self.G, self.K, self.low, self.high = kin.jacobian, arm.K, low, high
        error = np.minimum(TENSION_ERROR_N, TENSION_ERROR_SHARE * arm.f_max)  # (M,) N
        self.need = float((np.abs(self.G).max(axis=1) * error).max()) / POSE_ERROR_RAD
        gravity = backend.gravity_derivative(theta)
        self.base = 0.5 * (gravity + gravity.T)
        self.curve_high = backend.length_hessian(theta, high, kin.cache)
        self.curve_low = (self.curve_high if np.array_equal(low, high)
                          else backend.length_hessian(theta, low, kin.cache))

    def tension(self, share: float) -> np.ndarray:
        return (1.0 - share) * self.low + share * self.high

    def stable(self, share: float, length_held: np.ndarray) -> bool:
        """Stiff enough (``need``) with the tensions ``share`` of the way from low to high and
        the wires of ``length_held`` (bool mask) length-controlled."""
        return self.smallest(share, length_held) >= self.need

    def smallest(self, share: float, length_held: np.ndarray) -> float:
        """The smallest stiffness eigenvalue in that state (N·m/rad)."""
        f = self.tension(share)
        H = (self.base + (1.0 - share) * self.curve_low + share * self.curve_high
             + self.G.T @ ((self.K * (f + 1.0) * length_held)[:, None] * self.G))
        return float(np.linalg.eigvalsh(0.5 * (H + H.T))[0])


def _candidates(G: np.ndarray, tension: np.ndarray) -> Iterator[np.ndarray]:
    """Held sets to try: the greedy one, then other sets of N, N+1, ... M muscles (at most
    ``MAX_CANDIDATE_SETS`` of them)."""
    n_muscles, n_joints = G.shape
    greedy = held_muscles(G, tension)
    yield greedy
    greedy_set = tuple(np.flatnonzero(greedy))
    combos = itertools.chain.from_iterable(
        itertools.combinations(range(n_muscles), size) for size in range(n_joints, n_muscles + 1))
    for combo in itertools.islice((c for c in combos if c != greedy_set), MAX_CANDIDATE_SETS):
        mask = np.zeros(n_muscles, dtype=bool)
        mask[list(combo)] = True
        yield mask


def holdable(arm: ArmModel, theta: np.ndarray, tension: np.ndarray,
             kin: Kinematics | None = None) -> bool:
    """Whether some holding keeps the arm at ``theta`` under the QP ``tension``: every wire
    length-held there is the stiffest holding (each held wire adds K(f + 1) gᵢgᵢᵀ), and, the
    approach at ``tension`` itself being then the same state, ``plan_holding`` finds one.
    ``kin``: the backend's kinematics at ``theta``, if already computed."""
    tension = np.asarray(tension, float)
    stiff = _Stiffness(arm, np.asarray(theta, float), tension, tension, kin)
    return stiff.stable(1.0, np.ones(len(tension), dtype=bool))


def plan_holding(arm: ArmModel, theta: np.ndarray, tension: np.ndarray,
                 low: np.ndarray) -> Holding | None:
    """The holding of ``theta`` at the QP ``tension`` (M,), approached from ``low`` (M,), the
    lowest tensions that hold it; None when no choice of held muscles keeps the arm there
    (exactly when ``holdable`` is False).

    The approach blends ``low`` toward ``tension`` only as far as stability needs; the held
    set is the greedy one (``held_muscles``) where that is stable, else the first stable one,
    fewest muscles first.
    """
    stiff = _Stiffness(arm, np.asarray(theta, float), np.asarray(low, float),
                       np.asarray(tension, float))
    every = np.ones(len(tension), dtype=bool)
    sets: list[np.ndarray] = []  # candidate held sets, generated as far as needed
    holds: list[bool] = []       # each one's stability at the holding
    candidates = _candidates(stiff.G, tension)
    shares = APPROACH_BLENDS if not np.array_equal(low, tension) else APPROACH_BLENDS[:1]
    for share in shares:
        if not stiff.stable(share, every):
            continue
        for k in itertools.count():
            if k == len(sets):
                held = next(candidates, None)
                if held is None:
                    break
                sets.append(held)
                holds.append(stiff.stable(1.0, held))
            if holds[k] and stiff.stable(share, sets[k]):
                return Holding(held=sets[k], approach_tension=stiff.tension(share),
                               stiffness=min(stiff.smallest(share, every),
                                             stiff.smallest(share, sets[k]),
                                             stiff.smallest(1.0, sets[k])))
    return None
