"""Smooth function bases with analytic gradients, for the diagnosis' nuisance models.

Two bases, each for what it represents exactly or nearly so:

* :class:`PolyBasis` — full polynomials in θ up to a degree: the body schema ``h(θ)`` of the
  real arm (muscle routing is smooth but not of a known form).
* :class:`TrigBasis` — products over joints of {1, cos θ_j, sin θ_j}: the gravity potential of
  any serial chain of revolute joints lies exactly in this span (every point's height is
  multilinear in each joint's cos/sin), so fitting it to ``tau_gravity`` recovers the
  model's gravity *function* from samples, and its terms can be split by joint.
"""

from __future__ import annotations

import itertools

import numpy as np


class PolyBasis:
    """Monomials of total degree ≤ ``degree`` in θ scaled by ``scale`` (≈ unit range)."""

    def __init__(self, n_joints: int, degree: int, center: np.ndarray, scale: np.ndarray):
        self.exponents = np.array([e for d in range(degree + 1)
                                   for e in _compositions(n_joints, d)], dtype=int)
        self.center, self.scale = np.asarray(center, float), np.asarray(scale, float)
        self.degree = degree

    @property
    def size(self) -> int:
        return len(self.exponents)

    def _x(self, theta: np.ndarray) -> np.ndarray:
        return (np.asarray(theta, float) - self.center) / self.scale

    def _powers(self, theta: np.ndarray) -> np.ndarray:
        """(B, N, degree+1) table of x^d: monomials are then gathers, not powers."""
        x = self._x(theta)
        return x[:, :, None] ** np.arange(self.degree + 1)

    def _gather(self, powers: np.ndarray, exponents: np.ndarray) -> np.ndarray:
        n = powers.shape[1]
        return np.prod(powers[:, np.arange(n)[None, :], exponents], axis=2)  # (B, P)

    def values(self, theta: np.ndarray) -> np.ndarray:
        """(B, P) basis values."""
        return self._gather(self._powers(theta), self.exponents)

    def gradients(self, theta: np.ndarray) -> np.ndarray:
        """(B, P, N) ∂basis/∂θ."""
        powers = self._powers(theta)
        e = self.exponents
        out = np.empty((len(powers), len(e), powers.shape[1]))
        for k in range(powers.shape[1]):
            ek = e.copy()
            ek[:, k] = np.maximum(e[:, k] - 1, 0)
            out[:, :, k] = e[:, k] * self._gather(powers, ek) / self.scale[k]
        return out


def _compositions(n: int, total: int):
    """All length-n tuples of non-negative ints summing to ``total``."""
    if n == 1:
        yield (total,)
        return
    for first in range(total, -1, -1):
        for rest in _compositions(n - 1, total - first):
            yield (first, *rest)


class TrigBasis:
    """Products over joints of {1, cos θ_j, sin θ_j} (3^N terms, the constant dropped)."""

    def __init__(self, n_joints: int):
        self.codes = np.array([c for c in itertools.product(range(3), repeat=n_joints)
                               if any(c)], dtype=int)  # 0: 1, 1: cos, 2: sin

    @property
    def size(self) -> int:
        return len(self.codes)

    def _factors(self, theta: np.ndarray) -> np.ndarray:
        t = np.asarray(theta, float)
        return np.stack([np.ones_like(t), np.cos(t), np.sin(t)], axis=-1)  # (B, N, 3)

    def values(self, theta: np.ndarray) -> np.ndarray:
        f = self._factors(theta)
        n = f.shape[1]
        return np.prod(f[:, np.arange(n)[None, :], self.codes], axis=2)

    def gradients(self, theta: np.ndarray) -> np.ndarray:
        t = np.asarray(theta, float)
        f = self._factors(t)
        d = np.stack([np.zeros_like(t), -np.sin(t), np.cos(t)], axis=-1)
        n = f.shape[1]
        picked = f[:, np.arange(n)[None, :], self.codes]  # (B, P, N)
        dpicked = d[:, np.arange(n)[None, :], self.codes]
        out = np.empty(picked.shape)
        for k in range(n):
            others = np.prod(np.delete(picked, k, axis=2), axis=2)
            out[:, :, k] = dpicked[:, :, k] * others
        return out

    def involves(self, first_joint: int) -> np.ndarray:
        """Mask of terms that depend on some joint ≥ ``first_joint``."""
        return np.any(self.codes[:, first_joint:] > 0, axis=1)


def at_poses(cache: dict, theta: np.ndarray, compute, limit: int):
    """``compute(θ)`` memoised in ``cache`` by the poses' values (cleared past ``limit``
    entries): the fits evaluate the same pose sets many times."""
    theta = np.ascontiguousarray(theta, dtype=float)
    key = (theta.shape, hash(theta.tobytes()))
    if key not in cache:
        if len(cache) > limit:
            cache.clear()
        cache[key] = compute(theta)
    return cache[key]


class GravityFunction:
    """The model's gravity torque as a function, fitted to (θ, τ) samples.

    τ = ∇V with V in the trigonometric span (exact for revolute chains up to 6 joints;
    beyond that a degree-4 polynomial potential). Gives τ at other poses (joint offsets)
    and the potential of the links distal to joint k (link masses).
    """

    def __init__(self, theta: np.ndarray, tau: np.ndarray, ridge: float = 1e-10):
        theta, tau = np.asarray(theta, float), np.asarray(tau, float)
        n = theta.shape[1]
        if n <= 6:
            self.basis = TrigBasis(n)
        else:
            self.basis = PolyBasis(n, 4, np.zeros(n), np.ones(n))
        self.ridge = ridge
        self.coef = self.project(theta, tau)
        self.rms_error = float(np.sqrt(np.mean((self.torque(theta) - tau) ** 2)))
        self.rms_tau = float(np.sqrt(np.mean(tau**2)))

    def project(self, theta: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Coefficients in this basis of the torque field sampled as (θ, τ): the model's
        gravity, or one link's share of it (``robot_file.link_torques``)."""
        a = self._gradients(theta).transpose(0, 2, 1).reshape(-1, self.basis.size)
        ata = a.T @ a
        return np.linalg.solve(ata + self.ridge * np.trace(ata) / len(ata) * np.eye(len(ata)),
                               a.T @ np.asarray(tau, float).reshape(-1))

    def _gradients(self, theta: np.ndarray) -> np.ndarray:
        """Basis gradients, memoised: the fits evaluate many coefficients at fixed poses."""
        return at_poses(self.__dict__.setdefault("_cache", {}), theta, self.basis.gradients, 32)

    def torque(self, theta: np.ndarray, coef: np.ndarray | None = None) -> np.ndarray:
        c = self.coef if coef is None else coef
        return np.einsum("bpn,p->bn", self._gradients(theta), c)

    def derivative(self, theta: np.ndarray, eps: float = 1e-6) -> np.ndarray:
        """(B, N, N) ∂τ_i/∂θ_k by central differences of the analytic torque."""
        theta = np.asarray(theta, float)
        out = np.empty((*theta.shape, theta.shape[1]))
        for k in range(theta.shape[1]):
            dt = np.zeros(theta.shape[1])
            dt[k] = eps
            out[:, :, k] = (self.torque(theta + dt) - self.torque(theta - dt)) / (2 * eps)
        return out

    def distal_split(self, first_joint: int) -> tuple[np.ndarray, np.ndarray]:
        """Coefficients of the potential split into terms that move with joints ≥ k and the
        rest: a mass change distal to joint k scales the first exactly and the second in
        part (see module docs of :mod:`pimbs_learn.diagnosis.candidates`)."""
        if isinstance(self.basis, TrigBasis):
            mask = self.basis.involves(first_joint)
        else:
            mask = np.any(self.basis.exponents[:, first_joint:] > 0, axis=1)
        return np.where(mask, self.coef, 0.0), np.where(mask, 0.0, self.coef)

    def level(self, joint: int) -> np.ndarray:
        """Coefficients of the potential's terms whose last (most distal) joint is ``joint``.

        A mass change beyond joint k changes each proximal level by its own fraction (the
        changed link's lever on that level against the other links' on it), so each level
        gets its own scale.
        """
        codes = self.basis.codes if isinstance(self.basis, TrigBasis) else self.basis.exponents
        moving = codes > 0
        last = np.where(moving.any(axis=1), moving.shape[1] - 1 - np.argmax(moving[:, ::-1],
                                                                           axis=1), -1)
        return np.where(last == joint, self.coef, 0.0)
