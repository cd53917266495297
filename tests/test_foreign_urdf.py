"""A URDF as shipped by someone else: locked joints, continuous and mimic joints, package://
paths and meshes that are never needed; the reduced model's physics stays exact."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml

from pimbs_arm.model import ArmModel
from pimbs_calibration.description import DescriptionError, load_robot
from pimbs_calibration.urdf_model import UrdfError, prepared_xml

ROOT = Path(__file__).resolve().parents[1]
ACME_DIR = ROOT / "fixtures" / "foreign_arm"
ACME = ACME_DIR / "acme_left_arm.muscles.yaml"
ACME_URDF = ACME_DIR / "acme_humanoid_description" / "urdf" / "acme_left_arm.urdf"
TWO_LINK = ROOT / "calibration" / "robots"


@pytest.fixture(scope="module")
def acme() -> ArmModel:
    return ArmModel.load(ACME)


def _fd(f, theta: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Central differences of f (-> (K,)) along each joint: (K, N)."""
    cols = [(f(theta + eps * e) - f(theta - eps * e)) / (2 * eps) for e in np.eye(len(theta))]
    return np.stack(cols, axis=1)


def test_loads_as_shipped_with_unlisted_joints_locked(acme):
    robot = acme.robot
    assert robot.joints == ("l_shoulder_pitch", "l_shoulder_roll", "l_elbow_pitch")
    locked = dict(robot.locked)
    # values from the muscle file, the default 0, and the mimic following its leader
    assert locked == {"l_shoulder_yaw": 0.2, "l_wrist_roll": 0.5, "l_wrist_pitch": 0.0,
                      "l_gripper": 0.3, "l_gripper_mimic": -0.3}
    assert acme._model.nq == 3  # the continuous wrist roll and the rest are gone
    # the meshes behind package:// do not exist: nothing ever looked for them
    assert not (ACME_DIR / "acme_humanoid_description" / "meshes").exists()


def test_reduced_model_has_the_full_arms_gravity_and_geometry(acme):
    """Locking must not lose mass or move links: compare with the full URDF with the locked
    joints set to their values (pinocchio, every joint present)."""
    full = pin.buildModelFromXML(prepared_xml(ACME_URDF.read_text()))
    data = full.createData()
    locked = dict(acme.robot.locked)
    rng = np.random.default_rng(3)
    for theta in rng.uniform(acme.joint_range[:, 0], acme.joint_range[:, 1], (5, 3)):
        q = pin.neutral(full)
        for name, value in [*locked.items(), *zip(acme.joints, theta, strict=True)]:
            q[full.joints[full.getJointId(name)].idx_q] = value
        g = pin.computeGeneralizedGravity(full, data, q)
        iv = [full.joints[full.getJointId(j)].idx_v for j in acme.joints]
        np.testing.assert_allclose(acme.gravity_torque(theta), g[iv], atol=1e-10)
        pin.framesForwardKinematics(full, data, q)
        hand = data.oMf[full.getFrameId("l_hand_camera_frame")].translation
        np.testing.assert_allclose(acme.link_frames(theta)["l_hand_camera_frame"][1], hand,
                                   atol=1e-12)


def test_muscles_beyond_locked_joints_have_exact_jacobians(acme):
    theta = acme.joint_range.mean(axis=1) + 0.05
    G = acme.muscle_jacobian(theta)
    np.testing.assert_allclose(G, _fd(acme.h_geom, theta), atol=1e-8)
    el_flexor = acme.muscles.index("el_flexor")  # inserts beyond the locked wrist roll
    assert abs(G[el_flexor, 2]) > 0.02 and np.allclose(G[el_flexor, :2], 0)


def test_statics_hold_the_pose_the_tensions_were_planned_for(acme):
    theta = acme.joint_range.mean(axis=1)
    f = acme.tension_distribution(theta, 50.0)
    eq = acme.equilibrium("length", acme.length(theta, f), theta0=theta + 0.02)
    np.testing.assert_allclose(eq.theta, theta, atol=1e-6)
    np.testing.assert_allclose(eq.tension, f, rtol=1e-4)


def _variant(tmp_path: Path, edit_urdf, edit_muscles=None) -> Path:
    """A copy of the two-link robot with its URDF (and muscle file) edited."""
    urdf = (TWO_LINK / "two-link-4-muscle.urdf").read_text()
    (tmp_path / "two-link-4-muscle.urdf").write_text(edit_urdf(urdf))
    raw = yaml.safe_load((TWO_LINK / "two-link-4-muscle.muscles.yaml").read_text())
    if edit_muscles:
        edit_muscles(raw)
    path = tmp_path / "two-link-4-muscle.muscles.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_continuous_joint_drives_like_a_revolute_one(tmp_path):
    reference = ArmModel.load("two-link-4-muscle")
    path = _variant(tmp_path, lambda u: u.replace('<joint name="elbow_pitch" type="revolute">',
                                                  '<joint name="elbow_pitch" type="continuous">'))
    arm = ArmModel.load(path)
    assert arm.joint_limits[1, 1] > 1e3  # unlimited
    theta = np.array([0.2, -0.3])
    np.testing.assert_allclose(arm.muscle_jacobian(theta), reference.muscle_jacobian(theta))
    np.testing.assert_allclose(arm.gravity_torque(theta), reference.gravity_torque(theta))


MIMIC_LINK = """
  <link name="finger">
    <inertial><origin xyz="0 0 -0.05"/><mass value="0.8"/>
      <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial>
    <visual><geometry><mesh filename="package://nowhere/finger.stl"/></geometry></visual>
  </link>
  <joint name="finger_joint" type="revolute">
    <parent link="forearm"/><child link="finger"/>
    <origin xyz="0 0 -0.3"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="1" velocity="1"/>
    <mimic joint="elbow_pitch" multiplier="0.5" offset="0.1"/>
  </joint>
</robot>"""


def test_mimic_joint_follows_its_driven_leader_exactly(tmp_path):
    def add_finger_muscle(raw):  # m3 now inserts on the mimic-driven finger
        raw["muscles"][3]["path"].append({"link": "finger", "point": [0.03, 0.0, -0.04]})

    path = _variant(tmp_path, lambda u: u.replace("</robot>", MIMIC_LINK), add_finger_muscle)
    arm = ArmModel.load(path)
    assert dict((f[0], f[1:]) for f in arm.robot.followers) == {
        "finger_joint": ("elbow_pitch", 0.5, 0.1)}
    for theta in (np.array([0.1, -0.2]), np.array([-0.3, 0.4])):
        # G and gravity are the exact derivatives of length and potential energy, with the
        # finger moving at half the elbow's rate
        np.testing.assert_allclose(arm.muscle_jacobian(theta), _fd(arm.h_geom, theta),
                                   atol=1e-8)
        np.testing.assert_allclose(
            arm.gravity_torque(theta),
            _fd(lambda t: np.array([arm.potential_energy(t)]), theta)[0], atol=1e-6)
        H = arm.backend.length_hessian(theta, np.ones(arm.n_muscles))
        Hfd = _fd(lambda t: np.ones(arm.n_muscles) @ arm.muscle_jacobian(t), theta)
        np.testing.assert_allclose(H, Hfd, atol=1e-6)
    theta = np.array([0.1, -0.2])
    f = arm.tension_distribution(theta, 30.0)
    eq = arm.equilibrium("length", arm.length(theta, f), theta0=theta + 0.05)
    np.testing.assert_allclose(eq.theta, theta, atol=1e-6)


def test_package_url_resolves_through_ros_package_path(tmp_path, monkeypatch):
    raw = yaml.safe_load(ACME.read_text())
    del raw["package_path"]
    path = tmp_path / "acme.muscles.yaml"
    path.write_text(yaml.safe_dump(raw))
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    with pytest.raises(UrdfError, match="package 'acme_humanoid_description'.*ROS_PACKAGE_PATH"):
        load_robot(path)
    monkeypatch.setenv("ROS_PACKAGE_PATH", f"/nonexistent:{ACME_DIR}")
    assert load_robot(path).urdf_path == ACME_URDF.resolve()
    monkeypatch.delenv("ROS_PACKAGE_PATH")
    assert load_robot(path, package_path=[ACME_DIR]).urdf_path == ACME_URDF.resolve()


def test_xacro_is_refused_with_the_command_that_expands_it(tmp_path):
    shutil.copy(TWO_LINK / "two-link-4-muscle.muscles.yaml", tmp_path / "arm.muscles.yaml")
    xacro = tmp_path / "arm.urdf.xacro"
    xacro.write_text('<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="a">'
                     '<xacro:include filename="$(find arm)/x.xacro"/></robot>')
    raw = yaml.safe_load((tmp_path / "arm.muscles.yaml").read_text())
    raw["urdf"] = "arm.urdf.xacro"
    (tmp_path / "arm.muscles.yaml").write_text(yaml.safe_dump(raw))
    with pytest.raises(DescriptionError) as err:
        load_robot(tmp_path / "arm.muscles.yaml")
    message = str(err.value)
    assert "xacro arm.urdf.xacro > arm.urdf" in message and "field 'urdf'" in message
    assert str(tmp_path / "arm.muscles.yaml") in message and "\n" not in message


def test_driving_a_mimic_or_prismatic_joint_is_refused(tmp_path):
    path = _variant(tmp_path, lambda u: u.replace("</robot>", MIMIC_LINK),
                    lambda raw: raw["joints"].append({"name": "finger_joint",
                                                      "range": [-0.1, 0.1]}))
    with pytest.raises(DescriptionError, match="mimic joint of 'elbow_pitch'.*List its leader"):
        load_robot(path)
