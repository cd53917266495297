"""Joint angles from muscle lengths and tensions, for arms without joint encoders.

The motor length is ``l = h_geom(θ) − Δn(f)``, so the geometric lengths ``l + Δn(f)`` are
known from the readings and θ is their least-squares preimage (M ≥ N equations). A few
Gauss-Newton steps from the commanded pose converge; the result is only as good as the model,
which is why recordings say where θ came from (``theta_source``).
"""

from __future__ import annotations

import numpy as np

from pimbs_arm.model import ArmModel


def estimate_theta(model: ArmModel, length: np.ndarray, tension: np.ndarray,
                   theta0: np.ndarray, iterations: int = 20, tol: float = 1e-10
                   ) -> np.ndarray:
    """θ (N,) minimising ``||h_geom(θ) − (length + stretch(tension))||`` near ``theta0``."""
    target = np.asarray(length, float) + model.stretch(tension)
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    theta = np.clip(np.asarray(theta0, float), lo, hi)
    damping = 1e-9 * np.eye(model.n_joints)
    for _ in range(iterations):
        G = model.muscle_jacobian(theta)
        r = model.h_geom(theta) - target
        step = -np.linalg.solve(G.T @ G + damping, G.T @ r)
        theta = np.clip(theta + step, lo, hi)
        if np.linalg.norm(step) < tol:
            break
    return theta
