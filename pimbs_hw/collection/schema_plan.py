"""Commanding poses with a learned body schema instead of the geometric model.

The geometric model's muscle paths are a few millimetres off on a real arm, and a held
muscle's length error of 1 mm turns a joint by about 1 mm / moment arm (2° at 3 cm). A body
schema learned from collected samples knows the real paths, so for each target pose:

* tensions: the same minimum-effort QP as the geometric plan (``−Gᵀf = g(θ)``, f ≥ f_min),
  with the schema's G in the torque balance (an ATL-Map's G may depend on f: a short
  fixed-point iteration from the geometric tensions);
* held muscles' lengths: the schema's ``h(θ, f)`` at those tensions (tension-controlled
  muscles need no length);
* the approach before slack removal: the geometric approach lengths shifted by the schema's
  correction of each path at this pose;
* the move, the slack removal and its overshoot: exactly as in ``CollectionPlan``.

A schema is trusted where it was trained. A little beyond its training ranges (up to
``EXTRAPOLATION_BAND`` of a range) it is anchored: the schema at the nearest trained point
plus the geometric model's change from there (``EdgeAnchored``), so a network never
extrapolates on its own; the row says ``schema+geometric``. Further out, a QP that the
schema's G cannot satisfy, a schema that moves a path by more than its wire stretches from
slack to f_max, or commands under which the geometric model predicts a wire above
``OVERSHOOT_CEILING``·f_max or the arm far from the pose, the sample falls back to the
geometric plan. Every such sample carries a note saying why (the collection warns) and each
row records ``commanded_by``. The geometric model judges the commands in its own frame, with
the schema's correction of each path at the pose taken out: where the description is wrong
(the very reason to command with a schema) it would otherwise see every corrected length as
a wire pulled too short, and send the poses the schema knows best back to the geometry.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol

import numpy as np

from pimbs_arm.model import ArmModel, InfeasiblePoseError
from pimbs_hw.collection.plan import (
    MAX_POSE_EXCURSION,
    OVERSHOOT_CEILING,
    CollectionPlan,
    Target,
)

TENSION_ITERATIONS = 30  # linear convergence where G depends on f (an MLP ATL-Map)
TENSION_TOL = 1.0  # N per iteration: the fixed point f ↔ G(θ, f) reached (3 µm of stretch)
EXTRAPOLATION_BAND = 0.25  # fraction of a training range beyond which the schema is not used


class Schema(Protocol):
    """What commanding needs of a learned body schema (``pimbs_learn.BodySchema`` fits)."""

    joints: list[str]
    muscles: list[str]
    domain: Any  # .outside(theta, tension, joints, muscles) -> list[str]

    def length(self, theta: Any, f: Any = None) -> np.ndarray: ...

    def jacobian(self, theta: Any, f: Any = None) -> np.ndarray: ...


class EdgeAnchored:
    """The schema inside its training ranges; beyond them, the schema at the nearest trained
    point (θc, fc) plus the geometric model's change from there:

        l(θ, f) = h(θc, fc) + l_geom(θ, f) − l_geom(θc, fc)
        G(θ, f) = G_h(θc, fc) + G_geom(θ) − G_geom(θc)

    Continuous at the edge and exactly the schema inside. What the schema learned about the
    real paths is kept near the edge; only the change beyond it is the model's.
    """

    def __init__(self, schema: Schema, model: ArmModel) -> None:
        self.schema, self.model = schema, model

    def length(self, theta: np.ndarray, f: np.ndarray) -> np.ndarray:
        tc, fc = self.schema.domain.clip(theta, f)
        return (self.schema.length(tc, fc) + self.model.length(theta, f)
                - self.model.length(tc, fc))

    def jacobian(self, theta: np.ndarray, f: np.ndarray) -> np.ndarray:
        tc, fc = self.schema.domain.clip(theta, f)
        return (self.schema.jacobian(tc, fc) + self.model.muscle_jacobian(theta)
                - self.model.muscle_jacobian(tc))


class Unsafe(Exception):
    """The schema's commands for one sample are not to be sent; the message says why."""


class SchemaPlan(CollectionPlan):
    """``CollectionPlan`` whose holding commands come from a learned body schema."""

    def __init__(self, model: ArmModel, schema: Schema, n_samples: int, seed: int,
                 map_kind: str = "atl", pretension: np.ndarray | None = None) -> None:
        super().__init__(model, n_samples, seed, map_kind, pretension)
        if list(schema.joints) != list(model.joints) or \
                list(schema.muscles) != list(model.muscles):
            raise ValueError(
                f"the body schema is for joints {list(schema.joints)} and muscles "
                f"{list(schema.muscles)}, but robot {model.robot.name} has "
                f"{list(model.joints)} and {list(model.muscles)}; use a schema trained on "
                "this robot's recordings")
        self.schema, self.anchored = schema, EdgeAnchored(schema, model)
        self.f_max = np.array([m.f_max for m in model.robot.muscles])

    def target(self, i: int) -> Target:
        try:
            return self._learned(i)
        except Unsafe as why:  # the geometric plan is computed only where it is used
            return dataclasses.replace(super().target(i), commanded_by="geometric",
                                       note=f"geometric model commanded it: {why}")

    def _learned(self, i: int) -> Target:
        model, domain, theta = self.model, self.schema.domain, self.poses[i]
        far = domain.outside(theta, None, model.joints, margin=EXTRAPOLATION_BAND)
        if far:
            raise Unsafe(f"pose far outside the schema's training range ({'; '.join(far)})")
        # the geometric QP's tensions start the fixed point (InfeasiblePoseError: skipped)
        start = model.tension_distribution(theta, self.f_min[i], f_max=self.ceiling)
        tension = self._tensions(theta, self.f_min[i], start)
        far = domain.outside(theta, tension, model.joints, model.muscles, EXTRAPOLATION_BAND)
        if far:
            raise Unsafe(f"tension far outside the schema's training range ({'; '.join(far)})")
        outside = domain.outside(theta, tension, model.joints, model.muscles)
        schema = self.anchored
        try:  # held set and approach tensions from the description's stiffness at the pose
            holding = self.holding(theta, tension)
        except InfeasiblePoseError as exc:
            raise Unsafe(f"the description cannot hold this pose at the schema's tensions "
                         f"({exc})") from exc
        held = holding.held
        learned = schema.length(theta, tension)
        hold_command = np.where(held, learned, tension)
        hold_mode = tuple("length" if x else "tension" for x in held)
        # The schema's correction of each path at this pose, carried to the approach lengths
        # (the geometric plan's: the holding's approach tensions).
        approach_length = (model.length(theta, holding.approach_tension)
                           + (learned - model.length(theta, tension)))
        correction = learned - model.length(theta, tension)
        self._check_correction(correction)
        ceiling = np.maximum(OVERSHOOT_CEILING * self.f_max, tension)
        self._check(("length",) * model.n_muscles, approach_length - correction, theta,
                    ceiling, "approach")
        self._check(hold_mode, np.where(held, hold_command - correction, hold_command), theta,
                    ceiling, "holding")
        approach, overshoot = self._overshoot(i, theta, tension, held, hold_mode, hold_command)
        note = (f"outside the schema's training range ({'; '.join(outside)}): commanded with "
                "the schema at the nearest trained point and the geometric model beyond it"
                if outside else "")
        return Target(index=i, theta=theta, f_min=self.f_min[i], tension=tension, held=held,
                      approach_length=approach_length, hold_mode=hold_mode,
                      hold_command=hold_command, approach=approach,
                      overshoot_command=overshoot,
                      commanded_by="schema+geometric" if outside else "schema", note=note)

    def _tensions(self, theta: np.ndarray, f_min: np.ndarray, start: np.ndarray
                  ) -> np.ndarray:
        """QP tensions with the schema's G(θ, f), iterated to a fixed point in f."""
        f = start
        for _ in range(TENSION_ITERATIONS):
            G = self.anchored.jacobian(theta, f)
            try:
                new = self.model.tensions_for(theta, G, f_min, f_max=self.ceiling)
            except InfeasiblePoseError as exc:
                raise Unsafe(f"the schema's moment arms cannot hold this pose ({exc})") from exc
            done = np.abs(new - f).max() < TENSION_TOL
            f = new
            if done:
                return f
        raise Unsafe("the tensions do not settle with the schema's G(θ, f)")

    def _check_correction(self, correction: np.ndarray) -> None:
        """The schema's correction of each path within the wire's whole stretch (slack to
        f_max): a schema that moves a path further than that is not describing this arm."""
        bound = self.model.stretch(self.f_max)
        far = np.flatnonzero(np.abs(correction) > bound)
        if far.size:
            k = int(far[0])
            raise Unsafe(f"the schema moves {self.model.muscles[k]}'s path "
                         f"{correction[k] * 1e3:+.1f} mm from the description's, more than "
                         f"the wire stretches from slack to f_max ({bound[k] * 1e3:.1f} mm)")

    def _check(self, mode: tuple[str, ...], command: np.ndarray, theta: np.ndarray,
               ceiling: np.ndarray, what: str) -> None:
        """The geometric model's verdict on commands, given in its own frame (the schema's
        correction of each path at the pose taken out): the arm near the pose, no wire
        high. What it judges is the schema's tensions and moment arms; its lengths are
        judged by ``_check_correction``."""
        try:
            eq = self.model.equilibrium(list(mode), command, theta0=theta)
        except Exception as exc:  # noqa: BLE001 - no prediction: do not trust the commands
            raise Unsafe(f"the geometric model cannot predict the {what} ({exc})") from exc
        high = np.flatnonzero(eq.tension > ceiling + 1e-6)
        if high.size:
            k = int(high[0])
            raise Unsafe(f"the geometric model predicts {self.model.muscles[k]} at "
                         f"{eq.tension[k]:.0f} N in the {what} (limit {ceiling[k]:.0f} N)")
        off = float(np.abs(eq.theta - theta).max())
        if off > MAX_POSE_EXCURSION:
            raise Unsafe(f"the geometric model predicts the {what} {off:.2f} rad from the "
                         f"pose (limit {MAX_POSE_EXCURSION} rad)")
