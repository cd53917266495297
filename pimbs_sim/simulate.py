"""The paper's simulated body-schema data set, and "real" data with a concealed effect.

Per sample (Sec. III-A of the paper): θ uniform in the joint range (the seeded sequence of
:mod:`pimbs_arm.poses`, shared with ``collect``: a pose the muscles cannot hold within
f_max is replaced by a feasible draw); gravity torque and geometric lengths from the model;
tensions from the QP ``min fᵀf s.t. −Gᵀf = τ, f ≥ f_min`` with ``f_min = 0`` (AL-Map) or
uniform in [10, 300] N per muscle, at most 3/4 of the weakest f_max (ATL-Map); lengths with
the elastic stretch ``f = exp(KΔn) − 1``.

Like a real collection, the recording also carries times, approach directions (the sign
of each muscle's length change on the way from the previous pose), motor temperatures that
rise with load (first-order thermal model) and sensor noise; a ``SensorModel``
(:mod:`pimbs_sim.sensors`) adds loadcell and encoder latency and loadcell hysteresis, and sets
the heating. With effects from
:mod:`pimbs_sim.effects` the data obey the *true* arm while ``tau_gravity`` is still
computed from the model, exactly as on hardware. Poses, f_min draws and noise come from
separate seeded streams, so a concealed and a clean recording of one seed pair by
``sample``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pimbs_arm.model import ArmModel, InfeasiblePoseError
from pimbs_arm.poses import ATL_F_MIN, PosePlan, atl_floor_range, hold_ceiling, plan_poses
from pimbs_recording.format import make_meta
from pimbs_sim.effects import T_REF, Effect, World
from pimbs_sim.sensors import SensorModel, SensorNoise, SensorReadout, ThermalModel

__all__ = ["ATL_F_MIN", "simulate", "SensorModel", "SensorNoise", "ThermalModel",
           "approach_direction"]
START = np.datetime64("2026-01-01T09:00:00", "us")  # fixed, so files of one seed are equal


def approach_direction(previous: np.ndarray, current: np.ndarray,
                       threshold: float = 1e-4) -> np.ndarray:
    """+1 where a muscle lengthened into the pose, −1 where it shortened, 0 if still."""
    delta = current - previous
    return np.where(delta > threshold, 1, np.where(delta < -threshold, -1, 0)).astype(np.int8)


def simulate(arm: ArmModel, n_samples: int, map_kind: str = "atl", seed: int = 0,
             effects: tuple[Effect, ...] = (), noise: float = 1.0,
             sample_period: float = 4.0, noise_seed: int | None = None,
             start: np.datetime64 = START,
             progress: Callable[[int], None] | None = None,
             poses: PosePlan | None = None, sensors: SensorModel | None = None,
             ) -> tuple[dict[str, np.ndarray], dict]:
    """Simulate ``n_samples`` static samples; returns (columns, metadata) for the recording.

    ``noise_seed`` draws other sensor noise for the same poses (default: from ``seed``), so a
    "real" and a reference recording of the same poses need not share their noise.
    ``progress(done)`` is called every 100 samples and at the end (a 5-DOF arm takes
    about 0.4 ms per sample: 100 000 samples run for most of a minute). ``poses``: a plan
    to simulate instead of the seeded draws (``pimbs_arm.poses_file``).
    ``sensors`` says how the boards read the arm (:mod:`pimbs_sim.sensors`: noise, motor
    heating — how closely temperature follows load —, latency, hysteresis); the default
    ``SensorModel()`` is the plain sensor of ``pimbs simulate``, whose recordings it leaves
    unchanged.
    """
    if map_kind not in ("al", "atl"):
        raise ValueError(f"map must be 'al' or 'atl', not {map_kind!r}")
    noise_rng = np.random.default_rng([seed if noise_seed is None else noise_seed, 2])
    world = World(arm, tuple(effects))
    sensors = SensorModel() if sensors is None else sensors
    sigma = sensors.noise.scaled(noise)
    thermal = sensors.thermal
    readout = SensorReadout(sensors, arm.n_muscles)

    plan = plan_poses(arm, n_samples, seed, map_kind) if poses is None else poses
    theta_cmd = plan.poses
    n, m = arm.n_joints, arm.n_muscles
    out = {k: np.zeros((n_samples, w)) for k, w in
           (("theta", n), ("tension", m), ("length", m), ("temperature", m),
            ("tau_gravity", n))}
    approach = np.zeros((n_samples, m), dtype=np.int8)
    prev_length = np.zeros(m)  # the arm starts at the home pose, unloaded
    temp = np.full(m, thermal.ambient)
    for i in range(n_samples):
        f_min = plan.drawn_floors[i]
        theta_true = world.true_pose(theta_cmd[i])
        tension = _hold(world.arm, theta_true, f_min)
        length = world.arm.length(theta_true, tension)
        approach[i] = approach_direction(prev_length, length)
        prev_length = length
        temp = thermal.step(temp, tension, sample_period)
        temperature = temp + noise_rng.normal(0, sigma.temperature, m)
        reading, logged_length = readout.read(
            tension, world.read_tension(tension, approach[i], temperature), length)
        theta_meas = theta_cmd[i] + noise_rng.normal(0, sigma.theta, n)
        out["theta"][i] = theta_meas
        out["tension"][i] = reading + noise_rng.normal(0, sigma.tension, m)
        out["length"][i] = logged_length + noise_rng.normal(0, sigma.length, m)
        out["temperature"][i] = temperature
        out["tau_gravity"][i] = arm.gravity_torque(theta_meas)
        if progress is not None and ((i + 1) % 100 == 0 or i + 1 == n_samples):
            progress(i + 1)
    jitter = noise_rng.uniform(0, 0.5, n_samples) if noise else np.zeros(n_samples)
    times = start + ((np.arange(n_samples) * sample_period + jitter) * 1e6).astype(
        "timedelta64[us]")
    data = {"sample": np.arange(n_samples), "time": times, "theta_command": theta_cmd,
            "approach": approach, **out}
    meta = make_meta(arm.joints, arm.muscles, "simulation", robot=arm.robot.name,
                     seed=seed, map=map_kind, generator="pimbs simulate",
                     f_min=[0.0, 0.0] if map_kind == "al" else list(atl_floor_range(arm)),
                     joint_range=arm.joint_range.tolist(), K=arm.K.tolist(),
                     noise=noise, theta_source="simulation",
                     replaced_poses=list(plan.replaced), scaled_floors=list(plan.scaled),
                     # the simulated loadcells were zeroed (read right) at T_REF
                     loadcell_zero_temperature_C=T_REF)
    return data, meta


def _hold(arm: ArmModel, theta: np.ndarray, f_min: np.ndarray) -> np.ndarray:
    """The planned tensions (within the plan's ceiling); a concealed effect may make the true
    arm need more, which it then really pulls, as a real arm would."""
    try:
        return arm.tension_distribution(theta, f_min, f_max=hold_ceiling(arm))
    except InfeasiblePoseError:
        return arm.tension_distribution(theta, f_min)
