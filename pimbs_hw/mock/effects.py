"""The hook through which a concealed physics effect changes the simulated arm.

The mock accepts any object (or a list of them) with some of these methods; a missing method
means "no change". ``pimbs_sim.effects.Effect`` provides all three, so
``MockArm(..., effect=parse_effect("tendon_friction:0.2"))`` just works.

    physics(arm: ArmModel) -> ArmModel
        The true arm the boards move (other mass, stiffness, routing). Called once.
    true_pose(arm, theta_reported) -> theta_true
        Joint-encoder error: the encoder reports ``theta_reported`` when the arm is at
        ``theta_true``. The mock reports ``theta + (theta - true_pose(theta))``.
    read_tension(arm, tension, approach, temperature) -> reading
        What the loadcell reads for the true (joint-side) tension; ``approach`` is +1 when
        the muscle lengthened into the pose, -1 shortened, 0 unknown. Must be affine in
        ``tension`` per muscle (friction scale, offset, drift all are): tension-controlled
        boards servo on the reading, and the mock inverts it from two evaluations.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np


class MockEffect(Protocol):  # documentation of the duck type; every method is optional
    def physics(self, arm: Any) -> Any: ...
    def true_pose(self, arm: Any, theta: np.ndarray) -> np.ndarray: ...
    def read_tension(self, arm: Any, tension: np.ndarray, approach: np.ndarray,
                     temperature: np.ndarray) -> np.ndarray: ...


class EffectStack:
    """Several effects applied in order; an empty stack is the ideal arm."""

    def __init__(self, effects: object | Sequence[object] | None) -> None:
        if effects is None:
            effects = ()
        elif not isinstance(effects, Sequence):
            effects = (effects,)
        self.effects = tuple(effects)

    def physics(self, arm: Any) -> Any:
        for effect in self.effects:
            if hasattr(effect, "physics"):
                arm = effect.physics(arm)
        return arm

    def joint_reading(self, arm: Any, theta: np.ndarray) -> np.ndarray:
        out = np.array(theta, dtype=float)
        for effect in self.effects:
            if hasattr(effect, "true_pose"):
                out = out + (theta - effect.true_pose(arm, theta))
        return out

    def read_tension(self, arm: Any, tension: np.ndarray, approach: np.ndarray,
                     temperature: np.ndarray) -> np.ndarray:
        out = np.asarray(tension, dtype=float)
        for effect in self.effects:
            if hasattr(effect, "read_tension"):
                out = effect.read_tension(arm, out, approach, temperature)
        return out

    def true_tension(self, arm: Any, reading: np.ndarray, approach: np.ndarray,
                     temperature: np.ndarray) -> np.ndarray:
        """Tension whose reading is ``reading`` (inverse of the affine read_tension)."""
        if not self.effects:
            return np.asarray(reading, dtype=float)
        n = len(reading)
        r0 = self.read_tension(arm, np.zeros(n), approach, temperature)
        r1 = self.read_tension(arm, np.ones(n), approach, temperature)
        return (np.asarray(reading) - r0) / np.where(np.abs(r1 - r0) > 1e-12, r1 - r0, 1.0)
