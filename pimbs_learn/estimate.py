"""Joint angles from muscle lengths and tensions: the body schema run backwards.

A robot without joint encoders knows its motor lengths l and loadcell tensions f; its body
schema h(θ, f) says which pose explains them. θ is the least-squares preimage
``argmin ||h(θ, f) − l||²`` within the joint ranges (M ≥ N equations), found by
Levenberg–Marquardt with projection onto the range. Muscle paths are smooth but not convex
in θ, so it starts from several poses (the range's centre and seeded draws), runs a few
steps from each, and finishes from the best. The same solver serves a learned schema and
the geometric model (``GeometricSchema``), so a user sees what learning bought.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

DEG = 180.0 / np.pi


class LengthModel(Protocol):
    """A body schema as the estimator needs it: batched (B, N), (B, M) numpy in SI units."""

    def length(self, theta: Any, f: Any = None) -> np.ndarray: ...

    def jacobian(self, theta: Any, f: Any = None) -> np.ndarray: ...


def _length_and_jacobian(model: LengthModel, theta: np.ndarray, f: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Both from one evaluation where the model offers it (a network computes G alongside
    the lengths anyway), else from its two calls."""
    both = getattr(model, "length_and_jacobian", None)
    if both is not None:
        return both(theta, f)
    return model.length(theta, f), model.jacobian(theta, f)


class GeometricSchema:
    """The robot description's model (``ArmModel``) behind the body-schema API.

    ``l = h_geom(θ) − Δn(f)`` and ``G = ∂h_geom/∂θ`` (independent of f).
    """

    def __init__(self, arm: Any) -> None:
        self.arm = arm
        self.joints, self.muscles = list(arm.joints), list(arm.muscles)

    def length(self, theta: Any, f: Any = None) -> np.ndarray:
        return self.arm.length(theta, 0.0 if f is None else f)

    def jacobian(self, theta: Any, f: Any = None) -> np.ndarray:
        return self.arm.muscle_jacobian(theta)


def batched_geometric(arm: Any) -> Any:
    """The description's model evaluated for many poses at once (``PriorSchema``, torch), or
    the per-pose :class:`GeometricSchema` where the tensor model does not cover the
    description (non-revolute joints)."""
    from pimbs_learn.prior import PriorUnavailable
    from pimbs_learn.prior_schema import PriorSchema

    try:
        return PriorSchema(arm)
    except PriorUnavailable:
        return GeometricSchema(arm)


@dataclass(frozen=True)
class Estimate:
    """theta (B, N) rad; residual (B,) m: rms over muscles of h(θ̂, f) − l."""

    theta: np.ndarray
    residual: np.ndarray


def estimate_joint_angles(model: LengthModel, length: np.ndarray, tension: np.ndarray,
                          joint_range: np.ndarray, starts: int = 5, seed: int = 0,
                          iterations: int = 60) -> Estimate:
    """θ̂ (B, N) for lengths (B, M) m and tensions (B, M) N, within joint_range (N, 2)."""
    length = np.atleast_2d(np.asarray(length, float))
    tension = np.atleast_2d(np.asarray(tension, float))
    rng_ = np.asarray(joint_range, float)
    lo, hi = rng_[:, 0], rng_[:, 1]
    b, n = len(length), len(lo)
    draws = np.random.default_rng(seed).uniform(lo, hi, (max(starts - 1, 0), n))
    first = np.concatenate([(0.5 * (lo + hi))[None], draws])  # (S, N)
    s = len(first)
    # Stage 1: a few steps from every start; stage 2: the best start of each sample, to the end.
    theta = np.repeat(first[None], b, axis=0).reshape(b * s, n)
    stage1 = _levenberg_marquardt(model, np.repeat(length, s, axis=0),
                                  np.repeat(tension, s, axis=0), theta, lo, hi, 4)
    best = stage1.residual.reshape(b, s).argmin(axis=1)
    theta = stage1.theta.reshape(b, s, n)[np.arange(b), best]
    return _levenberg_marquardt(model, length, tension, theta, lo, hi, iterations)


def _levenberg_marquardt(model: LengthModel, target: np.ndarray, f: np.ndarray,
                         theta: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                         iterations: int, tol: float = 1e-10) -> Estimate:
    """Batched projected LM: every row is its own problem with its own damping."""
    theta = np.clip(theta, lo, hi)
    h, jac = _length_and_jacobian(model, theta, f)
    r = h - target
    cost = np.einsum("bm,bm->b", r, r)
    lam = np.full(len(theta), 1e-3)
    active = np.ones(len(theta), bool)
    eye = np.eye(theta.shape[1])
    for _ in range(iterations):
        idx = np.flatnonzero(active)
        if not idx.size:
            break
        J = jac[idx]
        jtj = J.transpose(0, 2, 1) @ J
        grad = np.einsum("bmn,bm->bn", J, r[idx])
        diag = np.einsum("bnn->bn", jtj)
        a = jtj + (lam[idx, None] * (diag + 1e-12 * diag.max(axis=1, keepdims=True) + 1e-30)
                   )[:, :, None] * eye
        step = -np.linalg.solve(a, grad[:, :, None])[:, :, 0]
        cand = np.clip(theta[idx] + step, lo, hi)
        # G of the candidate comes with its lengths: kept where the step is accepted
        hc, jc = _length_and_jacobian(model, cand, f[idx])
        rc = hc - target[idx]
        cc = np.einsum("bm,bm->b", rc, rc)
        ok = cc < cost[idx]
        moved = np.abs(cand - theta[idx]).max(axis=1)
        acc = idx[ok]
        theta[acc], r[acc], lam[acc], jac[acc] = cand[ok], rc[ok], lam[acc] / 3.0, jc[ok]
        small = ok & ((moved < tol) | (cost[idx] - cc < 1e-12 * cost[idx]))
        cost[acc] = cc[ok]
        lam[idx[~ok]] *= 5.0
        active[idx[small | (lam[idx] > 1e10)]] = False
    return Estimate(theta, np.sqrt(cost / target.shape[1]))


def rms_error_deg(estimate: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """(N,) rms over samples of the joint-angle error, in degrees (NaN rows skipped)."""
    err = np.asarray(estimate, float) - np.asarray(measured, float)
    ok = np.isfinite(err).all(axis=1)
    return np.sqrt(np.mean(err[ok] ** 2, axis=0)) * DEG


@dataclass(frozen=True)
class JointAngleReport:
    """Estimated joint angles of some samples by a learned schema and the geometric model.

    ``rms_error_deg`` (N,) against the recorded θ; the geometric fields are None where no
    robot description was available to build the geometric model. ``rows``: the indices of
    the samples estimated (all of them unless the report was bounded).
    """

    joints: list[str]
    theta: np.ndarray
    rms_error_deg: np.ndarray
    residual_m: np.ndarray
    geometric_theta: np.ndarray | None
    geometric_rms_error_deg: np.ndarray | None
    joint_range: np.ndarray
    range_source: str
    rows: np.ndarray | None = None

    def to_json(self) -> dict[str, Any]:
        def listed(x: np.ndarray | None) -> list | None:
            return None if x is None else np.asarray(x).tolist()

        return {"joints": self.joints, "rms_error_deg": listed(self.rms_error_deg),
                "geometric_rms_error_deg": listed(self.geometric_rms_error_deg),
                "residual_rms_m": float(np.sqrt(np.mean(self.residual_m ** 2))),
                "joint_range": listed(self.joint_range), "joint_range_from": self.range_source,
                "theta_estimate": listed(self.theta),
                "rows": listed(self.rows),
                "geometric_theta_estimate": listed(self.geometric_theta)}

    def line(self) -> str:
        """One line for a terminal: learned (geometric) rms per joint."""
        parts = []
        for k, name in enumerate(self.joints):
            geo = ("" if self.geometric_rms_error_deg is None
                   else f" (geometric {self.geometric_rms_error_deg[k]:.3g}°)")
            parts.append(f"{name} {self.rms_error_deg[k]:.3g}°{geo}")
        return ", ".join(parts)


def geometric_model(robot: str | None, joints: list[str], muscles: list[str]) -> Any:
    """The ``ArmModel`` of ``robot`` if it loads and has these joints and muscles, else None.

    A schema learned on a recording of an arm PIMBS has no description of still estimates
    joint angles; it just has no geometric model to compare with.
    """
    if not robot:
        return None
    from pimbs_arm.model import ArmModel

    try:
        arm = ArmModel.load(robot)
    except Exception:  # noqa: BLE001 - no usable description: no geometric comparison
        return None
    if list(arm.joints) != list(joints) or list(arm.muscles) != list(muscles):
        return None
    return arm


def joint_angle_report(schema: Any, theta: np.ndarray, tension: np.ndarray,
                       length: np.ndarray, robot: str | None = None, starts: int = 5,
                       seed: int = 0, max_rows: int | None = None) -> JointAngleReport:
    """Estimate θ from (l, f) of each sample with ``schema`` and with the geometric model.

    The search range is the robot's joint limits where its description is available (the
    arm can be anywhere it can physically go), else the schema's training range. With
    ``max_rows`` at most that many samples (a seeded draw, in their order) are estimated:
    a summary after training must not cost more than the training as the data set grows.
    """
    rows = None
    if max_rows is not None and len(theta) > max_rows:
        rows = np.sort(np.random.default_rng(seed).permutation(len(theta))[:max_rows])
        theta, tension, length = theta[rows], tension[rows], length[rows]
    arm = geometric_model(robot or schema.meta.get("robot"), schema.joints, schema.muscles)
    if arm is not None:
        joint_range, source = arm.joint_limits, f"joint limits of {arm.robot.name}"
    else:
        joint_range, source = schema.domain.theta, "training range of the schema"
    est = estimate_joint_angles(schema, length, tension, joint_range, starts, seed)
    geo_theta = geo_rms = None
    if arm is not None:
        geo_theta = estimate_joint_angles(batched_geometric(arm), length, tension,
                                          joint_range, starts, seed).theta
        geo_rms = rms_error_deg(geo_theta, theta)
    return JointAngleReport(list(schema.joints), est.theta, rms_error_deg(est.theta, theta),
                            est.residual, geo_theta, geo_rms, np.asarray(joint_range), source,
                            rows)
