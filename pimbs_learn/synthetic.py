"""A closed-form synthetic body for tests and benchmarks (no robot model needed).

h_geom(θ) = R θ + Q (cos θ − 1) (per joint), so G = R − Q·diag(sin θ) is known exactly;
τ = −Gᵀf holds by construction, and l = h_geom(θ) − log1p(f)/K as in the design's sign
convention. With Q = 0 the body is linear (G = R everywhere).
"""

from __future__ import annotations

import numpy as np

from pimbs_learn.data import Samples

K_ELASTIC = 1000.0  # the paper's K, 1/m


def body(n_joints: int, n_muscles: int, seed: int, linear: bool = False
         ) -> tuple[np.ndarray, np.ndarray]:
    """Moment-arm matrix R (M,N) of ±(1..3) cm and curvature Q (M,N) of up to 1 cm."""
    rng = np.random.default_rng(seed)
    r = rng.uniform(0.01, 0.03, (n_muscles, n_joints)) * rng.choice([-1, 1],
                                                                     (n_muscles, n_joints))
    q = np.zeros_like(r) if linear else rng.uniform(-0.01, 0.01, r.shape)
    return r, q


def h_geom(theta: np.ndarray, r: np.ndarray, q: np.ndarray) -> np.ndarray:
    return theta @ r.T + (np.cos(theta) - 1) @ q.T


def muscle_jacobian(theta: np.ndarray, r: np.ndarray, q: np.ndarray) -> np.ndarray:
    """G (B, M, N)."""
    return r[None] - q[None] * np.sin(theta)[:, None, :]


def synthetic_samples(n_samples: int, n_joints: int = 2, n_muscles: int = 4, seed: int = 0,
                      atl: bool = True, linear: bool = False, body_seed: int = 1234,
                      theta_range: float = 0.5) -> Samples:
    """Samples of the synthetic body: θ uniform in ±theta_range, f in [10, 300] N (ATL)
    or a fixed smooth function of θ (AL, so that l is a function of θ alone)."""
    r, q = body(n_joints, n_muscles, body_seed, linear)
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-theta_range, theta_range, (n_samples, n_joints))
    if atl:
        f = rng.uniform(10.0, 300.0, (n_samples, n_muscles))
    else:
        f = 100.0 + 50.0 * np.sin(theta @ np.abs(r).T * 40.0)
    g = muscle_jacobian(theta, r, q)
    tau = -np.einsum("bmn,bm->bn", g, f)
    length = h_geom(theta, r, q) - np.log1p(f) / K_ELASTIC
    return Samples(theta=theta, tension=f, length=length, tau=tau,
                   joints=tuple(f"j{i}" for i in range(n_joints)),
                   muscles=tuple(f"m{i}" for i in range(n_muscles)), robot="synthetic")
