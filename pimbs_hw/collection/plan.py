"""What to command for each sample: the seeded pose sequence and the tensions that hold it.

Everything random is drawn up front from the seed, with the same streams as
``pimbs_sim.simulate`` (``pimbs_arm.poses``: poses from ``[seed, 0]``, ATL
tension floors from ``[seed, 1]``, replacements of poses the muscles cannot hold within f_max
from ``[seed, 3, i]``), so a collection and ``pimbs simulate`` of one seed command the same
poses in the same order (their rows pair up by ``sample``), and ``--resume`` continues the
very same sequence, which holds no pose the model knows to be infeasible.

Approach directions (stream ``[seed, 2]``): capstan friction makes a loadcell read more or
less than the joint-side tension depending on the direction of the wire's last motion, and
only a motion beyond the friction band (``pimbs_recording.approach.BAND_M``) reverses it. The
slack take-up alone ends almost every muscle shortening, often by less than the band, which
leaves friction ill-defined and unidentifiable. So each sample ends with a deliberate
excursion: the slack take-up goes ``APPROACH_TRAVEL`` past the holding command and the final
ramp comes back, so every muscle's last motion is larger than a full friction reversal
(2 bands) in a known direction. Held muscles get a seeded random direction (an overshoot in
length, which moves the pose a little: the tension-controlled muscles give way, nobody
fights); a tension-controlled muscle's direction is that of its geometric motion on the way
back, topped up by a tension overshoot (bounded by its floor and ``OVERSHOOT_CEILING``·f_max)
where the geometry alone moves it less than ``APPROACH_TRAVEL``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pimbs_arm.holding import Holding, plan_holding
from pimbs_arm.model import ArmModel, InfeasiblePoseError
from pimbs_arm.poses import (
    MAPS,
    PosePlan,
    atl_floor_range,
    hold_ceiling,
    plan_poses,
    unstable_message,
)
from pimbs_recording.approach import BAND_M

APPROACH_TRAVEL = 2 * BAND_M + 4e-4  # m, final motion into each pose: > a full friction reversal
OVERSHOOT_CEILING = 0.75  # no wire is overshot beyond this fraction of f_max
MAX_POSE_EXCURSION = 0.2  # rad the held overshoot may move a joint
EXCURSION_SHARE = 0.2     # of a joint's range: the most it may run off a pose being held
MIN_EXCURSION = 0.1       # rad: ... but never less (loading swings a joint by a few 0.01 rad)
GEOMETRIC_MIN = 3e-4      # m: below this the geometry does not pick a free muscle's direction


def pose_excursion(model: ArmModel) -> np.ndarray:
    """(N,) rad each joint may run off the pose it is being loaded at before the pose is
    given up: ``MAX_POSE_EXCURSION``, or a fifth of a narrow joint's range (at least
    ``MIN_EXCURSION``). A joint whose balance is off runs toward a stop; with MyoSuite's
    torso (lumbar bending over 0.7 rad, rotation over 0.17 rad) 0.2 rad let it reach its
    stop and swing a held wire into the boards' ceiling before the guard saw anything;
    loading its poses swings the rotation by up to 0.07 rad on the way to a pose it holds."""
    lo, hi = np.asarray(model.joint_range, float).T
    return np.clip(EXCURSION_SHARE * (hi - lo), MIN_EXCURSION, MAX_POSE_EXCURSION)


@dataclass(frozen=True)
class Target:
    """The commands for one sample.

    ``approach_length``: every muscle length-controlled at the geometric length minus the
    stretch of the lowest tensions that hold the pose (``CollectionPlan.approach_tension``:
    the AL-Map's QP with each floor at the pretension); it moves the arm to the pose.
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
    approach: np.ndarray         # (M,) ±1: direction of each muscle's final motion (+1 out)
    overshoot_command: np.ndarray  # (M,) hold_mode command reached before the final ramp
    commanded_by: str | None = None  # "schema" / "geometric" when a learned schema is in use
    note: str = ""                   # why this sample fell back from the schema (warned)


class CollectionPlan:
    """The whole seeded sequence of targets for ``n_samples`` samples of one robot."""

    def __init__(self, model: ArmModel, n_samples: int, seed: int, map_kind: str = "atl",
                 pretension: np.ndarray | None = None, poses: PosePlan | None = None) -> None:
        if map_kind not in MAPS:
            raise ValueError(f"map must be one of {', '.join(MAPS)}, not {map_kind!r}")
        self.model, self.n_samples, self.seed, self.map_kind = model, n_samples, seed, map_kind
        floor = np.array([m.f_floor for m in model.robot.muscles])
        # A real wire is never commanded slack: the AL-Map's f_min = 0 becomes each floor.
        self.pretension = floor if pretension is None else np.asarray(pretension, float)
        # chosen poses (a poses file) or the seeded sequence
        poses = plan_poses(model, n_samples, seed, map_kind) if poses is None else poses
        self.poses, self.f_min, self.replaced = poses.poses, poses.floors, poses.replaced
        self.scaled = poses.scaled
        self.ceiling = hold_ceiling(model)
        self.floor = floor
        self.directions = np.random.default_rng([seed, 2]).choice(
            np.array([-1, 1], dtype=np.int8), (n_samples, model.n_muscles))

    def target(self, i: int) -> Target:
        """Commands for sample ``i`` (every planned pose is feasible, see ``poses``)."""
        model, theta = self.model, self.poses[i]
        tension = model.tension_distribution(theta, self.f_min[i], f_max=self.ceiling)
        holding = self.holding(theta, tension)
        held = holding.held
        h = model.h_geom(theta)
        hold_command = np.where(held, h - model.stretch(tension), tension)
        hold_mode = tuple("length" if x else "tension" for x in held)
        approach, overshoot = self._overshoot(i, theta, tension, held, hold_mode, hold_command)
        return Target(index=i, theta=theta, f_min=self.f_min[i], tension=tension, held=held,
                      approach_length=h - model.stretch(holding.approach_tension),
                      hold_mode=hold_mode, hold_command=hold_command,
                      approach=approach, overshoot_command=overshoot)

    def balance(self, theta: np.ndarray, floor: np.ndarray | None = None) -> np.ndarray:
        """The lowest tensions that hold ``theta``: the QP with every floor at the pretension
        or ``floor``, whichever is higher (``InfeasiblePoseError`` where none do)."""
        floor = self.pretension if floor is None else np.maximum(floor, self.pretension)
        return self.model.tension_distribution(theta, np.minimum(floor, self.ceiling),
                                               f_max=self.ceiling)

    def holding(self, theta: np.ndarray, tension: np.ndarray) -> Holding:
        """How ``theta`` is held at ``tension`` (``pimbs_arm.holding``): the held muscles and
        the approach tensions, the lowest that hold the pose (the QP with every floor at the
        pretension), raised toward ``tension`` where the arm would not stay there.

        Equal pretensions do not balance a pose: their net torque turns the arm until the
        wires balance it. Where the moment arms leave a direction soft (MyoSuite's finger:
        its flexors and extensor pull the two proximal joints nearly alike), that turn ran the
        approach to the joint limits, 0.4 rad and more from the pose.
        """
        holding = plan_holding(self.model, theta, tension, self.balance(theta))
        if holding is None:
            raise InfeasiblePoseError(unstable_message(self.model, theta))
        return holding

    def _overshoot(self, i: int, theta: np.ndarray, tension: np.ndarray, held: np.ndarray,
                   hold_mode: tuple[str, ...], hold_command: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Final directions and the command overshot before coming back to the holding."""
        model, travel = self.model, APPROACH_TRAVEL
        d = self.directions[i].astype(float)
        over = np.where(held, hold_command - d * travel, hold_command)  # +1: short, then out
        try:  # where the held overshoot puts the free muscles' motors (tensions unchanged)
            moved = model.equilibrium(list(hold_mode), over, theta0=theta).length
            back = model.length(theta, tension) - moved  # their motion on the way back
        except Exception:  # noqa: BLE001 - no prediction: the tension overshoot does it all
            back = np.zeros_like(tension)
        d = np.where(held | (np.abs(back) < GEOMETRIC_MIN), d, np.sign(back))
        extra = np.maximum(travel - d * back, 0.0)  # stretch still to add, in direction d
        f_max = np.array([m.f_max for m in model.robot.muscles])
        ceiling = np.maximum(OVERSHOOT_CEILING * f_max, tension)
        for _ in range(4):  # the held muscles balance the overshoot: keep all wires safe
            f_over = np.clip(model.tension_from_stretch(model.stretch(tension) + d * extra),
                             self.floor, ceiling)
            candidate = np.where(held, over, f_over)
            if self._safe(hold_mode, candidate, theta, ceiling):
                return d.astype(np.int8), candidate
            extra = extra / 2
        if not self._safe(hold_mode, over, theta, ceiling):
            over = hold_command  # no safe overshoot: the tracker records what happened
        return d.astype(np.int8), over

    def _safe(self, hold_mode: tuple[str, ...], command: np.ndarray, theta: np.ndarray,
              ceiling: np.ndarray) -> bool:
        """The model's equilibrium under ``command``: near the pose, no wire slack or high."""
        try:
            eq = self.model.equilibrium(list(hold_mode), command, theta0=theta)
        except Exception:  # noqa: BLE001 - no prediction, no overshoot
            return False
        return bool(np.abs(eq.theta - theta).max() <= MAX_POSE_EXCURSION
                    and (eq.tension >= self.floor - 1e-6).all()
                    and (eq.tension <= ceiling + 1e-6).all())

    def meta(self) -> dict:
        """Metadata keys that identify the sequence (checked when resuming)."""
        return {"seed": self.seed, "samples": self.n_samples, "map": self.map_kind,
                "f_min": [float(self.pretension.min()), float(self.pretension.max())]
                if self.map_kind == "al" else list(atl_floor_range(self.model)),
                "replaced_poses": list(self.replaced), "scaled_floors": list(self.scaled)}

