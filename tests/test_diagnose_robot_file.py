"""What the robot file adds to a diagnosis: each muscle's routing as the body schema's anchor.

(Each link's own gravity is tested with the heavier upper arm in
``test_diagnose_confounded.py``.)
"""

from __future__ import annotations

import numpy as np
import pytest

from pimbs_arm.model import ArmModel
from pimbs_learn.diagnosis import robot_file
from pimbs_learn.diagnosis.run import diagnose
from pimbs_recording.format import write_recording
from pimbs_sim.simulate import simulate

ROBOT = "left-arm-5dof"


def _pair(tmp_path, n=200, seed=5):
    arm = ArmModel.load(ROBOT)
    paths = []
    for name in ("sim", "real"):
        data, meta = simulate(arm, n, "atl", seed=seed, noise_seed=seed + (name == "real") * 1000)
        paths.append(tmp_path / f"{name}.parquet")
        write_recording(paths[-1], data, meta)
    return paths[1], paths[0]


def _length_noise(result: dict) -> float:
    return float(np.median(result["model"]["noise_length_m"]))


def test_the_files_routing_anchors_the_schema_of_a_five_joint_arm(tmp_path):
    """200 rows allow a cubic schema in five joints; it misses the wires' routing by tens of
    micrometres, which the noise estimate takes for length noise (measured 27–50 µm on
    eight of its ten muscles, against the simulated 5 µm per reading), and the torques'
    noise with it. Anchored to the file's routing, the schema's polynomial only follows how
    the arm differs from its file, and the estimates fall to what the sensors make
    (7–10 µm)."""
    real, ref = _pair(tmp_path)
    alone, _ = diagnose(real, ref, design_poses=0)
    anchored, _ = diagnose(real, ref, robot=ROBOT, design_poses=0)
    assert not alone["model"]["schema_from_robot_file"]
    assert anchored["model"]["schema_from_robot_file"]
    assert _length_noise(anchored) < 0.4 * _length_noise(alone), (
        anchored["model"]["noise_length_m"], alone["model"]["noise_length_m"])
    torque = np.array(anchored["model"]["noise_torque_Nm"])
    assert np.all(torque < 0.6 * np.array(alone["model"]["noise_torque_Nm"])), torque
    assert anchored["effects"] == [] and anchored["ambiguous"] == []


def test_a_rerouted_arm_still_corrects_the_files_routing(tmp_path):
    """Every via point 4 mm off the file: lengths differ from the file's by millimetres
    that vary with the pose, and a polynomial correction predicts them clearly better than
    the file's routing as it is. The schema learns the routing (it is not physics left
    out), the lengths fit to the sensors' noise, and nothing is named."""
    from pimbs_sim.effects import parse_effect

    arm = ArmModel.load(ROBOT)
    paths = []
    for name, effects in (("sim", ()), ("real", (parse_effect("routing:0.004", seed=21),))):
        data, meta = simulate(arm, 200, "atl", seed=3, noise_seed=3 + (name == "real"),
                              effects=effects)
        paths.append(tmp_path / f"{name}.parquet")
        write_recording(paths[-1], data, meta)
    result, _ = diagnose(paths[1], paths[0], robot=ROBOT, design_poses=0)
    assert result["model"]["schema_degree"] >= 1
    assert _length_noise(result) < 15e-6, result["model"]["noise_length_m"]
    assert result["effects"] == [] and result["ambiguous"] == [], result["effects"]


class _Unrelated:
    """A routing that has nothing to do with the arm: lengths that ripple with every joint."""

    def __init__(self, arm: ArmModel) -> None:
        self.m = arm.n_muscles

    def at(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        wave = 0.01 * np.sin(40.0 * theta)  # (B, N)
        h = np.repeat(wave.sum(1, keepdims=True), self.m, axis=1)
        jac = np.repeat((0.4 * np.cos(40.0 * theta))[:, None, :], self.m, axis=1)
        return h, jac


def test_a_routing_that_predicts_nothing_is_left_out(tmp_path, monkeypatch):
    """The file's routing anchors the schema only where it predicts held-out rows better
    than the polynomial alone: a file of another arm must not make the fit worse."""
    real, ref = _pair(tmp_path, n=120)
    alone, _ = diagnose(real, ref, design_poses=0)
    monkeypatch.setattr(robot_file, "FileRouting", _Unrelated)
    result, _ = diagnose(real, ref, robot=ROBOT, design_poses=0)
    assert not result["model"]["schema_from_robot_file"]
    # as without the file, but for its elasticity (the reference's fit is within 1 % of it)
    assert _length_noise(result) == pytest.approx(_length_noise(alone), rel=0.02)
