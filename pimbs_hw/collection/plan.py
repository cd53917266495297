"""What to command for each sample: the seeded pose sequence and the tensions that hold it.

Everything random is drawn up front from the seed, with the same streams as
``calibration.simulate`` (poses from ``[seed, 0]``, ATL tension floors from ``[seed, 1]``), so
a collection and ``pimbs simulate`` of one seed command the same poses in the same order
(their rows pair up by ``sample``), and ``--resume`` continues the very same sequence.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.arm_model import ArmModel, sample_poses
from calibration.simulate import ATL_F_MIN

MAPS = ("al", "atl")


@dataclass(frozen=True)
class Target:
    """The commands for one sample.

    ``approach_length``: every muscle length-controlled at the geometric length minus the
    stretch of a low pretension (moves the arm to the pose; some wires may be slack).
    ``hold_mode``/``hold_command``: slack removal. ``held`` muscles (loaded ones whose
    Jacobian rows span the joints well) keep a length that gives their QP tension at the pose, the
    others are tension-controlled at their QP tension: the pose stays fixed by the held
    muscles and, since the QP tensions balance gravity, nobody fights.
    """

    index: int
    theta: np.ndarray          # (N,) commanded pose
    f_min: np.ndarray          # (M,) tension floor of the QP
    tension: np.ndarray        # (M,) QP tensions holding theta against gravity
    held: np.ndarray           # (M,) bool, length-controlled while holding
    approach_length: np.ndarray  # (M,) m
    hold_mode: tuple[str, ...]   # (M,) "length" | "tension"
    hold_command: np.ndarray     # (M,) m for held muscles, N for the others


class CollectionPlan:
    """The whole seeded sequence of targets for ``n_samples`` samples of one robot."""

    def __init__(self, model: ArmModel, n_samples: int, seed: int, map_kind: str = "atl",
                 pretension: np.ndarray | None = None) -> None:
        if map_kind not in MAPS:
            raise ValueError(f"map must be one of {', '.join(MAPS)}, not {map_kind!r}")
        self.model, self.n_samples, self.seed, self.map_kind = model, n_samples, seed, map_kind
        floor = np.array([m.f_floor for m in model.robot.muscles])
        # A real wire is never commanded slack: the AL-Map's f_min = 0 becomes each floor.
        self.pretension = floor if pretension is None else np.asarray(pretension, float)
        self.poses = sample_poses(model.joint_range, n_samples,
                                  np.random.default_rng([seed, 0]))
        if map_kind == "atl":
            drawn = np.random.default_rng([seed, 1]).uniform(
                *ATL_F_MIN, (n_samples, model.n_muscles))
            self.f_min = np.maximum(drawn, floor)
        else:
            self.f_min = np.broadcast_to(floor, (n_samples, model.n_muscles)).copy()

    def target(self, i: int) -> Target:
        """Commands for sample ``i``; raises ``InfeasiblePoseError`` if no tensions hold it."""
        model, theta = self.model, self.poses[i]
        tension = model.tension_distribution(theta, self.f_min[i])
        held = held_muscles(model.muscle_jacobian(theta), tension)
        h = model.h_geom(theta)
        hold_command = np.where(held, h - model.stretch(tension), tension)
        return Target(index=i, theta=theta, f_min=self.f_min[i], tension=tension, held=held,
                      approach_length=h - model.stretch(self.pretension),
                      hold_mode=tuple("length" if x else "tension" for x in held),
                      hold_command=hold_command)

    def meta(self) -> dict:
        """Metadata keys that identify the sequence (checked when resuming)."""
        return {"seed": self.seed, "samples": self.n_samples, "map": self.map_kind,
                "f_min": [float(self.pretension.min()), float(self.pretension.max())]
                if self.map_kind == "al" else list(ATL_F_MIN)}


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
