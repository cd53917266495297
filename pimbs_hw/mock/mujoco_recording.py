"""A recording of MuJoCo as the plant, made without a bus or a clock: as fast as the CPU runs.

``pimbs collect --plant`` drives a MuJoCo arm through the simulated boards in real time (or a
few times faster): minutes per recording. For a population of arms the same physics is
stepped offline: ``MujocoPlant`` (each muscle a position-controlled motor winding its tendon
through the series elastic element, MuJoCo integrating the arm) is commanded pose after pose
and integrated until it is at rest, and only then read.

Per planned sample (``pimbs_arm.poses.plan_poses``, the poses and tension floors a collection
of the same seed holds): the planned tensions f* are the tension QP's at the pose θ* within
the plan's ceiling, the motor lengths the description's ``l = h(θ*) − Δn(f*)``. The motors are
walked there along the straight line from the previous pose and tensions (steps of at most
``STEP_RAD`` in every joint, ``STEP_S`` each), so no wire is jerked, then held until
``MujocoPlant.settled()`` (joints still for 0.2 s, motors at their targets). A pose that has
not settled ``timeout_s`` after its last command is skipped (no row) and counted.

What is logged is what the boards would report, read through the recording's
``pimbs_sim.sensors.SensorModel``: the joint angles MuJoCo integrated (plus a concealed encoder
offset), the plant's tensions through the loadcell's concealed effects, hysteresis, latency and
noise, the motor lengths through latency and noise, motor temperatures heated by the tensions
the plant really carried over the arm time it took (``ThermalModel``). ``tau_gravity`` is the
description's gravity at the measured angles, as on hardware; ``approach`` comes from the
motor lengths' changes. The plant may differ from the description (its own file: masses,
sites, friction, springs), and ``elastic_stiffness`` makes the plant's springs differ from the
description's K; ``link_mass`` and ``routing`` belong in the plant file and are refused here.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pimbs_arm.model import ArmModel, InfeasiblePoseError
from pimbs_arm.poses import PosePlan, atl_floor_range, hold_ceiling, plan_poses
from pimbs_hw.mock.mujoco_plant import MujocoPlant, ringing
from pimbs_recording.format import make_meta
from pimbs_sim.effects import T_REF, Effect, World
from pimbs_sim.sensors import SensorModel, SensorReadout
from pimbs_sim.simulate import START, approach_direction

STEP_RAD = 0.05   # rad: the largest step of any joint along the way to the next pose
STEP_S = 0.025    # s of arm time per step (2 rad/s)
CHUNK_S = 0.05    # s of arm time between checks for rest
READING_EFFECTS = ("tendon_friction", "tension_gain", "tension_offset", "thermal_drift")


@dataclass
class PlantRecordingStats:
    """How the recording went: skipped poses, arm time, wall time, the plant's ringing."""

    skipped: list[int] = field(default_factory=list)
    arm_s: float = 0.0
    wall_s: float = 0.0
    decay_s: float = 0.0        # slowest 1/e decay of a joint motion (``ringing``)
    settle_s: list[float] = field(default_factory=list)

    def to_json(self) -> dict:
        return {"skipped": self.skipped, "arm_s": round(self.arm_s, 2),
                "wall_s": round(self.wall_s, 2), "decay_s": round(self.decay_s, 4),
                "settle_s_median": float(np.median(self.settle_s)) if self.settle_s else None,
                "settle_s_max": float(np.max(self.settle_s)) if self.settle_s else None}


def record_plant(arm: ArmModel, plant_xml: str | Path, n_samples: int, map_kind: str = "atl",
                 seed: int = 0, effects: tuple[Effect, ...] = (),
                 sensors: SensorModel | None = None, noise: float = 1.0,
                 timeout_s: float = 8.0, progress: Callable[[int], None] | None = None,
                 poses: PosePlan | None = None,
                 ) -> tuple[dict[str, np.ndarray], dict, PlantRecordingStats]:
    """Record ``n_samples`` planned poses of ``arm`` (the description) on the MuJoCo plant
    ``plant_xml``; returns (columns, metadata, stats) for ``write_recording``.

    ``effects``: the loadcell's (``READING_EFFECTS``), ``joint_offset`` (the encoders read
    θ + δ) and ``elastic_stiffness`` (the plant's springs). Noise and the draw of poses are
    seeded as in ``pimbs_sim.simulate.simulate``. ``poses``: a plan to hold instead of the
    seeded draws (``pimbs_arm.poses_file``: the poses a diagnosis proposes), as ``simulate``
    takes it; ``n_samples`` is then its length.
    """
    t0 = time.perf_counter()
    sensors = SensorModel() if sensors is None else sensors
    plant_arm, reading, offset = _split_effects(arm, effects)
    world = World(arm, reading)
    sigma = sensors.noise.scaled(noise)
    noise_rng = np.random.default_rng([seed, 2])
    plan = plan_poses(arm, n_samples, seed, map_kind) if poses is None else poses
    n_samples = len(plan.poses)
    stats = PlantRecordingStats(decay_s=ringing(Path(plant_xml), arm.robot).decay_s)
    plant = MujocoPlant(Path(plant_xml), plant_arm)
    n, m = arm.n_joints, arm.n_muscles
    ceiling = hold_ceiling(arm)
    readout = SensorReadout(sensors, m)
    thermal = sensors.thermal
    temp = np.full(m, thermal.ambient)
    prev_length = np.zeros(m)
    theta_prev, tension_prev = plant.state.theta.copy(), plant.state.tension.copy()
    rows: dict[str, list] = {k: [] for k in ("sample", "time", "theta", "theta_command",
                                             "tension", "length", "temperature", "approach",
                                             "tau_gravity", "settle_s")}
    clock = 0.0
    for i in range(n_samples):
        theta_goal = plan.poses[i]
        try:
            f_goal = arm.tension_distribution(theta_goal, plan.floors[i], f_max=ceiling)
        except InfeasiblePoseError:
            f_goal = arm.tension_distribution(theta_goal, plan.floors[i])
        used, temp = _move(plant, arm, theta_prev, tension_prev, theta_goal, f_goal, thermal,
                           temp)
        settle, at_rest, temp = _settle(plant, thermal, temp, timeout_s)
        clock += used + settle
        stats.arm_s += used + settle
        theta_prev, tension_prev = theta_goal, f_goal
        if not at_rest:
            stats.skipped.append(i)
            continue
        stats.settle_s.append(settle)
        state = plant.state
        temp = thermal.step(temp, state.tension, sensors.read_after_s)
        clock += sensors.read_after_s
        approach = approach_direction(prev_length, state.length)
        prev_length = state.length.copy()
        temperature = temp + noise_rng.normal(0, sigma.temperature, m)
        tension, length = readout.read(
            state.tension, world.read_tension(state.tension, approach, temperature),
            state.length)
        theta = state.theta + offset + noise_rng.normal(0, sigma.theta, n)
        rows["sample"].append(i)
        rows["time"].append(clock)
        rows["theta"].append(theta)
        rows["theta_command"].append(theta_goal)
        rows["tension"].append(tension + noise_rng.normal(0, sigma.tension, m))
        rows["length"].append(length + noise_rng.normal(0, sigma.length, m))
        rows["temperature"].append(temperature)
        rows["approach"].append(approach)
        rows["tau_gravity"].append(arm.gravity_torque(theta))
        rows["settle_s"].append(settle)
        if progress is not None and ((i + 1) % 50 == 0 or i + 1 == n_samples):
            progress(i + 1)
    plant.close()
    data = _columns(rows, n, m)
    meta = make_meta(arm.joints, arm.muscles, "simulation", robot=arm.robot.name, seed=seed,
                     map=map_kind, generator="pimbs population",
                     f_min=[0.0, 0.0] if map_kind == "al" else list(atl_floor_range(arm)),
                     joint_range=arm.joint_range.tolist(), K=arm.K.tolist(), noise=noise,
                     theta_source="joint_encoders", replaced_poses=list(plan.replaced),
                     scaled_floors=list(plan.scaled),
                     skipped_samples=stats.skipped, loadcell_zero_temperature_C=T_REF)
    stats.wall_s = time.perf_counter() - t0
    return data, meta, stats


def _split_effects(arm: ArmModel, effects: tuple[Effect, ...]
                   ) -> tuple[ArmModel, tuple[Effect, ...], np.ndarray]:
    """(the plant's arm model: its springs, the loadcell's effects, the encoders' offset)."""
    plant_arm, reading, offset = arm, [], np.zeros(arm.n_joints)
    for e in effects:
        if e.name == "elastic_stiffness":
            plant_arm = e.physics(plant_arm)
        elif e.name == "joint_offset":
            offset = offset + e.at_joints(arm)
        elif e.name in READING_EFFECTS:
            reading.append(e)
        else:
            raise ValueError(f"{e.name} acts on the plant's body: write it into the plant "
                             "MJCF (a body's mass, a site's position) instead")
    return plant_arm, tuple(reading), offset


def _move(plant: MujocoPlant, arm: ArmModel, theta0: np.ndarray, f0: np.ndarray,
          theta1: np.ndarray, f1: np.ndarray, thermal, temp: np.ndarray
          ) -> tuple[float, np.ndarray]:
    """Walk the motors to the lengths of (theta1, f1) through the description's lengths of
    the straight line from (theta0, f0); returns (arm time used, temperatures)."""
    steps = max(1, int(np.ceil(np.abs(theta1 - theta0).max() / STEP_RAD)))
    modes = ("length",) * arm.n_muscles
    for s in np.linspace(0.0, 1.0, steps + 1)[1:]:
        theta = theta0 + s * (theta1 - theta0)
        f = f0 + s * (f1 - f0)
        plant.command(modes, arm.length(theta, f))
        state = plant.step(STEP_S)
        temp = thermal.step(temp, state.tension, STEP_S)
    return steps * STEP_S, temp


def _settle(plant: MujocoPlant, thermal, temp: np.ndarray, timeout_s: float
            ) -> tuple[float, bool, np.ndarray]:
    """Step until the plant is at rest or ``timeout_s`` has passed; (arm time, at rest,
    temperatures). A simulation that blew up (``MujocoPlant.failure``: it then stands still,
    which is no rest) is an error, not a row."""
    waited = 0.0
    while plant.failure is None and not plant.settled():
        if waited >= timeout_s:
            return waited, False, temp
        state = plant.step(CHUNK_S)
        temp = thermal.step(temp, state.tension, CHUNK_S)
        waited += CHUNK_S
    if plant.failure is not None:
        raise FloatingPointError(plant.failure)
    return waited, True, temp


def _columns(rows: dict[str, list], n: int, m: int) -> dict[str, np.ndarray]:
    def stacked(key: str, width: int, dtype=float) -> np.ndarray:
        return np.array(rows[key], dtype=dtype).reshape(len(rows[key]), width)

    times = START + (np.array(rows["time"]) * 1e6).astype("timedelta64[us]")
    return {"sample": np.array(rows["sample"], dtype=np.int64), "time": times,
            "theta": stacked("theta", n), "theta_command": stacked("theta_command", n),
            "tension": stacked("tension", m), "length": stacked("length", m),
            "temperature": stacked("temperature", m),
            "approach": stacked("approach", m, np.int8),
            "tau_gravity": stacked("tau_gravity", n), "settle_s": np.array(rows["settle_s"])}
