"""Where a body schema was trained, so that its users can tell when it extrapolates.

A network fitted to samples is only known to be right near them; outside the training
range of any joint or muscle tension it may be arbitrarily wrong while looking confident.
A controller that commands lengths from it must know that before it moves the arm, so the
per-joint θ range and per-muscle tension range of the training samples are stored in the
model file and checked here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

# Fraction of each range the schema may be used beyond its outermost training sample: the
# samples of a range are drawn uniformly, so the outermost ones fall short of its edge.
MARGIN = 0.05


@dataclass(frozen=True)
class Domain:
    """Training ranges: theta (N, 2) rad, tension (M, 2) N or None for an AL-Map."""

    theta: np.ndarray
    tension: np.ndarray | None

    @classmethod
    def from_samples(cls, theta: np.ndarray, tension: np.ndarray | None) -> Domain:
        th = np.stack([theta.min(axis=0), theta.max(axis=0)], axis=1)
        f = None if tension is None else np.stack([tension.min(axis=0),
                                                   tension.max(axis=0)], axis=1)
        return cls(th, f)

    @classmethod
    def from_meta(cls, meta: dict[str, Any]) -> Domain:
        """The stored ranges; for a model file without them, the scaling's ±max|x|."""
        d = meta.get("domain")
        if d is not None:
            f = d.get("tension")
            return cls(np.asarray(d["theta"], float), None if f is None else np.asarray(f, float))
        s = meta["scaling"]
        th = np.asarray(s["theta"], float)
        f = s.get("tension")
        return cls(np.stack([-th, th], axis=1),
                   None if f is None else np.stack([np.zeros(len(f)), np.asarray(f, float)],
                                                   axis=1))

    def to_json(self) -> dict[str, Any]:
        return {"theta": self.theta.tolist(),
                "tension": None if self.tension is None else self.tension.tolist(),
                "margin": MARGIN}

    def _widened(self, r: np.ndarray, margin: float) -> np.ndarray:
        pad = margin * (r[:, 1] - r[:, 0])
        return np.stack([r[:, 0] - pad, r[:, 1] + pad], axis=1)

    def outside(self, theta: np.ndarray, tension: np.ndarray | None = None,
                joints: list[str] | None = None, muscles: list[str] | None = None,
                margin: float = MARGIN) -> list[str]:
        """What of one pose (N,) and its tensions (M,) lies outside the training ranges.

        Empty when the schema interpolates; otherwise one phrase per offending joint or
        muscle, e.g. ``"elbow_pitch = 0.61 rad (trained -0.49 … 0.50)"``. ``margin``: the
        fraction of each range counted as inside beyond its outermost samples.
        """
        out: list[str] = []
        checks = [(np.asarray(theta, float), self.theta, joints, "rad")]
        if tension is not None and self.tension is not None:
            checks.append((np.asarray(tension, float), self.tension, muscles, "N"))
        for x, r, names, unit in checks:
            lo, hi = self._widened(r, margin).T
            for i in np.flatnonzero((x < lo) | (x > hi)):
                name = names[i] if names else f"#{i}"
                out.append(f"{name} = {x[i]:.3g} {unit} (trained {r[i, 0]:.3g} … "
                           f"{r[i, 1]:.3g})")
        return out

    def clip(self, theta: np.ndarray, tension: np.ndarray | None
             ) -> tuple[np.ndarray, np.ndarray | None]:
        """The nearest point (θ, f) inside the training ranges (with the margin)."""
        th_lo, th_hi = self._widened(self.theta, MARGIN).T
        theta = np.clip(theta, th_lo, th_hi)
        if tension is not None and self.tension is not None:
            f_lo, f_hi = self._widened(self.tension, MARGIN).T
            tension = np.clip(tension, f_lo, f_hi)
        return theta, tension
