"""The robot description's model as a batched body schema, for estimating many poses fast.

``GeometricSchema`` evaluates ``ArmModel`` one pose at a time through pinocchio, which is
what a collection plan needs; the joint-angle estimator evaluates hundreds of poses per
Levenberg–Marquardt step. The same model written as tensors (:mod:`pimbs_learn.prior`,
checked against ``ArmModel`` in the tests) gives lengths and G for the whole batch in one
call, so the geometric comparison costs milliseconds instead of seconds.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from pimbs_learn.prior import GeometricPrior, prior_arrays


class PriorSchema:
    """l = h_geom(θ) − log1p(f)/K and G = ∂h_geom/∂θ of an ``ArmModel``, batched (B, ·)."""

    def __init__(self, arm: Any) -> None:
        self.arm = arm
        self.joints, self.muscles = list(arm.joints), list(arm.muscles)
        self._prior = GeometricPrior.from_numpy(prior_arrays(arm))

    def length_and_jacobian(self, theta: Any, f: Any = None) -> tuple[np.ndarray, np.ndarray]:
        th = np.atleast_2d(np.asarray(theta, dtype=np.float64))
        ft = np.zeros((len(th), len(self.muscles))) if f is None else np.broadcast_to(
            np.asarray(f, dtype=np.float64), (len(th), len(self.muscles)))
        with torch.no_grad():
            h, g = self._prior(torch.from_numpy(np.array(th)), torch.from_numpy(np.array(ft)))
        return h.numpy(), g.numpy()

    def length(self, theta: Any, f: Any = None) -> np.ndarray:
        return self.length_and_jacobian(theta, f)[0]

    def jacobian(self, theta: Any, f: Any = None) -> np.ndarray:
        return self.length_and_jacobian(theta, f)[1]

