"""MJCF arms as robot descriptions: MuJoCo's own tendon lengths and Jacobians, its gravity, the
equilibrium, the defaults of a bare MJCF, a muscle file mapping tendons, and the commands."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_calibration.description import DescriptionError, load_robot
from pimbs_cli.main import main
from pimbs_recording.format import read_recording

ARMS = Path(__file__).resolve().parents[1] / "fixtures" / "mujoco"
PLANAR, SPATIAL = ARMS / "planar_2dof.xml", ARMS / "spatial_3dof.xml"

# Written in another style than the fixtures: <default> classes, radians, unnamed geoms, a
# slide joint (locked), a pulley splitting a tendon in two branches, a fixed tendon (a joint
# coupling, never a muscle), a site-only tendon and a tendon wrapping a cylinder on one side.
OTHER_STYLE = """
<mujoco model="other-style">
  <compiler angle="radian" autolimits="true"/>
  <default>
    <default class="wire"><site size="0.003" rgba="1 0 0 1"/></default>
    <default class="pulley"><geom type="cylinder" size="0.03 0.01" contype="0"
      conaffinity="0"/></default>
    <joint damping="0.1"/>
  </default>
  <worldbody>
    <site class="wire" name="o1" pos="-0.02 0.01 0.12"/>
    <site class="wire" name="o2" pos="0.035 -0.01 0.11"/>
    <site class="wire" name="o3" pos="0.0 0.03 0.1"/>
    <site class="wire" name="o4" pos="0.01 -0.04 0.1"/>
    <site name="side_a" pos="-0.1 0 0"/>
    <body name="slider" pos="0 0 0">
      <joint name="rail" type="slide" axis="0 0 1" range="-0.01 0.01" ref="0.0"/>
      <inertial pos="0 0 0" mass="0.2" diaginertia="1e-4 1e-4 1e-4"/>
      <body name="link1" pos="0 0 0" euler="0.1 0 0">
        <joint name="j1" type="hinge" axis="0 1 0" range="-0.8 0.8"/>
        <joint name="j2" type="hinge" axis="1 0 0.2" range="-0.5 0.5"/>
        <inertial pos="0.01 0 -0.12" mass="0.8" diaginertia="6e-3 6e-3 6e-4"/>
        <geom class="pulley" name="p1" zaxis="0 1 0"/>
        <site class="wire" name="i1" pos="-0.02 0 -0.1"/>
        <site class="wire" name="i2" pos="0.03 0.01 -0.1"/>
        <site class="wire" name="i3" pos="0.0 0.03 -0.1"/>
        <site class="wire" name="i4" pos="0.0 -0.03 -0.1"/>
        <site class="wire" name="m1" pos="-0.02 0 -0.2"/>
        <body name="link2" pos="0 0 -0.25">
          <joint name="j3" type="hinge" axis="0 1 0" range="-0.6 0.9"/>
          <inertial pos="0 0 -0.1" mass="0.4" diaginertia="2e-3 2e-3 2e-4"/>
          <site class="wire" name="e1" pos="-0.02 0 -0.05"/>
          <site class="wire" name="e2" pos="0.02 0 -0.05"/>
          <site class="wire" name="e3" pos="0.02 0.01 -0.08"/>
        </body>
      </body>
    </body>
  </worldbody>
  <tendon>
    <spatial name="front">
      <site site="o1"/><geom geom="p1" sidesite="side_a"/><site site="i1"/>
    </spatial>
    <fixed name="coupling"><joint joint="j1" coef="1"/><joint joint="j3" coef="-0.5"/></fixed>
    <spatial name="back"><site site="o2"/><site site="i2"/></spatial>
    <spatial name="split">
      <site site="o3"/><site site="i3"/>
      <pulley divisor="2"/><site site="o3"/><site site="i4"/>
    </spatial>
    <spatial name="roll"><site site="o4"/><site site="i4"/></spatial>
    <spatial name="elbow_front"><site site="m1"/><site site="e1"/></spatial>
    <spatial name="elbow_back"><site site="i2"/><site site="e2"/><site site="e3"/></spatial>
  </tendon>
</mujoco>
"""


@pytest.fixture(scope="module")
def other_style(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("mjcf") / "other_style.xml"
    path.write_text(OTHER_STYLE)
    return path


def _mujoco_truth(xml: Path, joints, tendons, theta: np.ndarray):
    """ten_length and ten_J straight from MuJoCo (mj_fwdPosition on a fresh MjData)."""
    model = mujoco.MjModel.from_xml_path(str(xml))
    data = mujoco.MjData(model)
    qadr = [model.jnt_qposadr[model.joint(j).id] for j in joints]
    dof = [model.jnt_dofadr[model.joint(j).id] for j in joints]
    tid = [model.tendon(t).id for t in tendons]
    data.qpos[qadr] = theta
    mujoco.mj_fwdPosition(model, data)
    J = np.zeros((model.ntendon, model.nv))
    mujoco.mju_sparse2dense(J, data.ten_J, model.ten_J_rownnz, model.ten_J_rowadr,
                            model.ten_J_colind)
    return data.ten_length[tid].copy(), J[np.ix_(tid, dof)]


def test_lengths_and_jacobians_are_mujocos_own(other_style):
    arm = ArmModel.load(other_style)
    # every hinge driven, the slide joint locked at qpos0, the fixed tendon not a muscle
    assert arm.joints == ("j1", "j2", "j3")
    assert dict(arm.robot.locked) == {"rail": 0.0}
    assert arm.muscles == ("front", "back", "split", "roll", "elbow_front", "elbow_back")
    rng = np.random.default_rng(3)
    poses = rng.uniform(arm.joint_range[:, 0], arm.joint_range[:, 1], (40, 3))
    for theta in [np.zeros(3), *arm.joint_range.T, *poses]:
        kin = arm.backend.kinematics(theta)
        length, J = _mujoco_truth(other_style, arm.joints, arm.muscles, theta)
        np.testing.assert_allclose(kin.length, length, rtol=0, atol=1e-12)
        np.testing.assert_allclose(kin.jacobian, J, rtol=0, atol=1e-12)
    # the pulley halves the second branch: the split tendon moves with both branches
    assert np.abs(arm.muscle_jacobian(poses)[:, 2]).max() > 1e-3


@pytest.mark.parametrize("xml", [PLANAR, SPATIAL], ids=["planar", "spatial"])
def test_jacobian_gravity_and_hessian_against_finite_differences(xml):
    arm = ArmModel.load(xml)
    rng = np.random.default_rng(0)
    eps, n = 1e-6, arm.n_joints
    for theta in rng.uniform(arm.joint_range[:, 0], arm.joint_range[:, 1], (6, n)):
        steps = eps * np.eye(n)
        fd = np.stack([(arm.h_geom(theta + s) - arm.h_geom(theta - s)) / (2 * eps)
                       for s in steps], axis=1)
        np.testing.assert_allclose(arm.muscle_jacobian(theta), fd, atol=1e-6)
        # gravity is what the muscles must supply: the gradient of the potential energy
        dE = np.array([(arm.potential_energy(theta + s) - arm.potential_energy(theta - s))
                       / (2 * eps) for s in steps])
        np.testing.assert_allclose(arm.gravity_torque(theta), dE, atol=1e-6)
        w = rng.uniform(10, 300, arm.n_muscles)
        big = 1e-4 * np.eye(n)
        fd_h = np.stack([(w @ arm.muscle_jacobian(theta + s) - w @ arm.muscle_jacobian(theta - s))
                         / 2e-4 for s in big], axis=1)
        H = arm.backend.length_hessian(theta, w)
        np.testing.assert_allclose(H, H.T)
        np.testing.assert_allclose(H, fd_h, atol=1e-3 * max(1.0, np.abs(fd_h).max()))
    # hanging straight down, a hinge about a horizontal axis needs no torque
    np.testing.assert_allclose(arm.gravity_torque(np.zeros(n)), 0.0, atol=1e-12)


@pytest.mark.parametrize("xml", [PLANAR, SPATIAL], ids=["planar", "spatial"])
def test_equilibrium_on_an_mjcf_arm_returns_to_the_commanded_pose(xml):
    arm = ArmModel.load(xml)
    rng = np.random.default_rng(1)
    lo, hi = arm.joint_range[:, 0], arm.joint_range[:, 1]
    for target in rng.uniform(lo + 0.2 * (hi - lo), hi - 0.2 * (hi - lo), (3, arm.n_joints)):
        f = arm.tension_distribution(target, 30.0)
        eq = arm.equilibrium("length", arm.length(target, f))
        assert eq.converged
        np.testing.assert_allclose(eq.theta, target, atol=1e-6)
        np.testing.assert_allclose(eq.tension, f, rtol=1e-4, atol=1e-3)


def test_bare_mjcf_defaults():
    robot = load_robot(SPATIAL)
    assert robot.mjcf_path == SPATIAL.resolve() and robot.muscle_path == SPATIAL.resolve()
    assert robot.name == "spatial-3dof" and robot.joint_encoders
    assert [m.board_id for m in robot.muscles] == [1, 2, 3, 4, 5, 6]  # tendon order
    assert [m.name for m in robot.muscles][-2:] == ["biceps", "triceps"]
    # the biceps' motor is force-limited to 500 N; the others get the default 600 N
    assert [m.f_max for m in robot.muscles] == [600.0] * 4 + [500.0, 600.0]
    assert {m.K for m in robot.muscles} == {1000.0} and {m.f_floor for m in robot.muscles} == {10}
    # sampling ranges are the joints' own ranges (degrees in this file), in rad
    np.testing.assert_allclose(robot.joint_range, np.deg2rad([[-25, 25], [-20, 20], [-45, 20]]))


def test_a_muscle_file_maps_tendons_to_boards_and_limits(tmp_path):
    (tmp_path / "arm.xml").write_text(SPATIAL.read_text())
    spec = {"robot": "lab-arm", "mjcf": "arm.xml", "joint_encoders": False,
            "joints": [{"name": "shoulder_pitch", "range": [-0.3, 0.3]}, {"name": "elbow"}],
            "lock": {"shoulder_roll": 0.1},
            "defaults": {"K": 800.0},
            "muscles": [{"name": "triceps", "board_id": 21, "f_max": 300.0},
                        {"name": "delt_front", "board_id": 22},
                        {"name": "biceps", "board_id": 23},
                        {"name": "delt_back", "board_id": 24, "protocol": "odrive-cansimple"}]}
    path = tmp_path / "lab.muscles.yaml"
    path.write_text(yaml.safe_dump(spec))
    arm = ArmModel.load(path)
    robot = arm.robot
    assert robot.name == "lab-arm" and not robot.joint_encoders
    assert arm.joints == ("shoulder_pitch", "elbow") and dict(robot.locked) == {
        "shoulder_roll": 0.1}
    assert arm.muscles == ("triceps", "delt_front", "biceps", "delt_back")
    assert [(m.board_id, m.f_max, m.K) for m in robot.muscles] == [
        (21, 300.0, 800.0), (22, 600.0, 800.0), (23, 500.0, 800.0), (24, 600.0, 800.0)]
    assert robot.muscles[3].protocol == "odrive-cansimple"
    # the locked roll is held: the biceps' moment arm matches MuJoCo at roll = 0.1
    model = mujoco.MjModel.from_xml_path(str(SPATIAL))
    data = mujoco.MjData(model)
    data.qpos[:] = [0.2, 0.1, -0.3]
    mujoco.mj_fwdPosition(model, data)
    np.testing.assert_allclose(arm.backend.kinematics(np.array([0.2, -0.3])).length,
                               data.ten_length[[5, 0, 4, 1]], atol=1e-12)


@pytest.mark.parametrize("change, field, words", [
    ({"muscles": [{"name": "nope"}]}, "muscles[0].name", "not a tendon of the MJCF"),
    ({"joints": [{"name": "rail"}]}, "joints[0].name", "not a hinge joint"),
    ({"joints": [{"name": "j1", "range": [-1.0, 0.5]}]}, "joints[0].range", "inside"),
    ({"lock": {"j1": 0.2}}, "lock.j1", "not a hinge or slide joint that is not driven"),
    ({"muscles": [{"name": "coupling"}]}, "muscles[0].name", "fixed tendon"),
    ({"muscles": [{"name": "front", "K": -1}]}, "muscles[0].K", "positive"),
    ({"muscles": [{"name": "front", "board_id": 3}, {"name": "back", "board_id": 3}]},
     "muscles[1].board_id", "also used"),
    ({"urdf": "arm.urdf"}, "mjcf", "both 'urdf' and 'mjcf'"),
])
def test_muscle_file_mistakes_name_the_field(tmp_path, other_style, change, field, words):
    (tmp_path / "arm.xml").write_text(other_style.read_text())
    path = tmp_path / "arm.muscles.yaml"
    path.write_text(yaml.safe_dump({"mjcf": "arm.xml", **change}))
    with pytest.raises(DescriptionError) as err:
        load_robot(path)
    assert err.value.field == field and words in str(err.value)
    assert str(path) in str(err.value)


def test_broken_or_foreign_xml_is_one_clear_line(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><bodyy/></worldbody></mujoco>")
    res = CliRunner().invoke(main, ["robot", str(bad)])
    assert res.exit_code == 1 and res.output.count("\n") == 1
    assert str(bad) in res.output and "MuJoCo cannot load this MJCF" in res.output
    assert "Traceback" not in res.output
    urdf = tmp_path / "arm.xml"
    urdf.write_text("<robot name='x'><link name='a'/></robot>")
    res = CliRunner().invoke(main, ["robot", str(urdf)])
    assert res.exit_code == 1 and "not an MJCF" in res.output and str(urdf) in res.output
    no_tendons = tmp_path / "bare.xml"
    no_tendons.write_text("<mujoco><worldbody><body><joint name='a'/><geom size='0.1'/>"
                          "</body></worldbody></mujoco>")
    res = CliRunner().invoke(main, ["robot", str(no_tendons)])
    assert res.exit_code == 1 and "has no spatial tendon" in res.output


def test_pimbs_robot_explains_an_mjcf_arm(tmp_path, other_style):
    png = tmp_path / "arm.png"
    res = CliRunner().invoke(main, ["robot", str(SPATIAL), "--poses", "30", "--plot", str(png),
                                    "--pose", "shoulder_pitch=0.3,elbow=-0.5"])
    assert res.exit_code == 0, res.output
    out = res.output
    assert f"MJCF {SPATIAL.resolve()}" in out and "driven joints (3" in out
    words = " ".join(out.split())  # a long tendon path goes on below itself
    assert "delt_front 1 10 600 1000 site front_origin > sphere shoulder_ball > " \
           "site front_insert" in words
    assert "biceps             5       10     500" in out
    assert out.count("ok at all 39 poses") == 3
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    res = CliRunner().invoke(main, ["robot", str(other_style), "--poses", "10"])
    assert "fixed tendons ignored (joint couplings, not muscles): coupling" in res.output
    assert "rail                   slide      at 0" in res.output
    assert "pulley /2" in res.output


def test_pimbs_simulate_writes_a_valid_recording_of_an_mjcf_arm(tmp_path):
    out = tmp_path / "planar.parquet"
    res = CliRunner().invoke(main, ["simulate", "--robot", str(PLANAR), "-n", "12",
                                    "--noise", "0", "--out", str(out)])
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    arm = ArmModel.load(PLANAR)
    assert rec.robot == "planar-2dof" and tuple(rec.joints) == arm.joints
    assert tuple(rec.muscles) == arm.muscles and rec.n_rows == 12
    # the torque balance of the recording holds with MuJoCo's gravity and moment arms
    theta, tension = rec.theta, rec.tension
    residual = arm.gravity_torque(theta) + np.einsum("bmn,bm->bn",
                                                     arm.muscle_jacobian(theta), tension)
    assert np.abs(residual).max() < 1e-6
    np.testing.assert_allclose(rec.tau_gravity, arm.gravity_torque(theta), atol=1e-9)


def test_concealed_link_mass_and_routing_change_the_mjcf_arm(tmp_path):
    from pimbs_sim.effects import parse_effect

    arm = ArmModel.load(PLANAR)
    heavy = parse_effect("mass:1.5").physics(arm)  # default: the last driven joint's body
    # the same change written into the MJCF, measured by MuJoCo from scratch
    changed = tmp_path / "heavy.xml"
    changed.write_text(PLANAR.read_text().replace('mass="0.6"', 'mass="0.9"'))
    truth = ArmModel.load(changed)
    theta = np.array([[0.3, -0.4], [-0.5, 0.2]])
    np.testing.assert_allclose(heavy.gravity_torque(theta), truth.gravity_torque(theta),
                               atol=1e-12)
    assert not np.allclose(arm.gravity_torque(theta), heavy.gravity_torque(theta))
    np.testing.assert_array_equal(arm.backend.mj_model.body_mass, [0.0, 1.0, 0.6])  # untouched
    moved = parse_effect("routing:0.004", seed=2).physics(arm)
    shift = np.abs(moved.h_geom(theta) - arm.h_geom(theta)).max()
    assert 1e-4 < shift < 0.05
    with pytest.raises(ValueError, match="'nope' is not a body with mass"):
        parse_effect("mass:1.5,link=nope").physics(arm)


def test_training_on_an_mjcf_arm_says_in_one_line_that_it_has_no_prior(tmp_path):
    rec = tmp_path / "s.parquet"
    assert CliRunner().invoke(main, ["simulate", "--robot", str(PLANAR), "-n", "40",
                                     "--out", str(rec)]).exit_code == 0
    res = CliRunner().invoke(main, ["train", str(rec), "--robot", str(PLANAR), "--epochs", "2",
                                    "--seed", "1"])
    assert res.exit_code == 0, res.output
    notes = [line for line in res.output.splitlines() if "no geometric prior" in line]
    assert len(notes) == 1 and "MJCF robot" in notes[0] and "learns the whole length map" \
        in notes[0]


def test_an_mjcf_arm_model_pickles_for_worker_processes():
    import pickle

    arm = ArmModel.load(SPATIAL)
    copy = pickle.loads(pickle.dumps(arm))
    theta = np.array([0.1, 0.2, -0.3])
    np.testing.assert_array_equal(copy.muscle_jacobian(theta), arm.muscle_jacobian(theta))
    np.testing.assert_array_equal(copy.gravity_torque(theta), arm.gravity_torque(theta))


# One hinge, five tendons, each declaring its largest tension another way: a muscle with its
# peak force, a muscle whose peak force MuJoCo derives (force="-1": scale / acc0), a geared
# force-limited motor, a geared control-limited motor, and a tendon no actuator declares
# anything for (a position servo's force depends on its gains and error: nothing declared).
DECLARED_FORCES = """
<mujoco model="declared-forces">
  <worldbody>
    <site name="a" pos="0.03 0 0.1"/><site name="b" pos="-0.03 0 0.1"/>
    <site name="c" pos="0.02 0 0.1"/><site name="d" pos="-0.02 0 0.1"/>
    <site name="e" pos="0.04 0 0.1"/>
    <body name="link" pos="0 0 0">
      <joint name="hinge" type="hinge" axis="0 1 0" range="-30 30"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="1"/>
      <site name="a1" pos="0.03 0 -0.1"/><site name="b1" pos="-0.03 0 -0.1"/>
      <site name="c1" pos="0.02 0 -0.1"/><site name="d1" pos="-0.02 0 -0.1"/>
      <site name="e1" pos="0.04 0 -0.1"/>
    </body>
  </worldbody>
  <tendon>
    <spatial name="given"><site site="a"/><site site="a1"/></spatial>
    <spatial name="derived"><site site="b"/><site site="b1"/></spatial>
    <spatial name="geared"><site site="c"/><site site="c1"/></spatial>
    <spatial name="bare"><site site="d"/><site site="d1"/></spatial>
    <spatial name="ctrl"><site site="e"/><site site="e1"/></spatial>
  </tendon>
  <actuator>
    <muscle name="m_given" tendon="given" force="300" lengthrange="0.1 0.3"/>
    <muscle name="m_derived" tendon="derived" scale="200" lengthrange="0.1 0.3"/>
    <motor name="m_geared" tendon="geared" gear="2" forcelimited="true" forcerange="-50 0"/>
    <motor name="m_ctrl" tendon="ctrl" gear="3" ctrllimited="true" ctrlrange="-40 0"/>
    <position name="m_servo" tendon="bare" kp="500"/>
  </actuator>
</mujoco>
"""


def test_actuators_declare_the_muscles_force_limits(tmp_path):
    """f_max of a bare MJCF is the tension MuJoCo's actuators can put on each tendon: a
    muscle's peak active force as MuJoCo's own muscle gain computes it (at the optimal length,
    at rest, fully active), a motor's force range times its gear; else the stated default."""
    path = tmp_path / "declared.xml"
    path.write_text(DECLARED_FORCES)
    f_max = {m.name: m.f_max for m in load_robot(path).muscles}
    model = mujoco.MjModel.from_xml_path(str(path))
    for name in ("m_given", "m_derived"):
        a = model.actuator(name).id
        lo, hi = model.actuator_gainprm[a, :2]  # the muscle's normalized operating range
        lr = model.actuator_lengthrange[a]
        optimal = lr[0] + (1.0 - lo) * (lr[1] - lr[0]) / (hi - lo)  # normalized length 1
        peak = -mujoco.mju_muscleGain(optimal, 0.0, lr, model.actuator_acc0[a],
                                      model.actuator_gainprm[a, :9])
        tendon = model.tendon(int(model.actuator_trnid[a, 0])).name
        assert f_max[tendon] == pytest.approx(peak, rel=1e-12)
    assert f_max["given"] == pytest.approx(300.0)
    assert f_max["derived"] == pytest.approx(200.0 / model.actuator_acc0[1])
    # each motor driven past its limit (MuJoCo clamps the control or the force): the tension
    # its transmission puts on the tendon is (generalized force) / (the tendon's moment arm)
    data = mujoco.MjData(model)
    ten_j = ArmModel.load(path).backend.kinematics(np.zeros(1)).jacobian
    for name, tendon, expected in (("m_geared", "geared", 100.0), ("m_ctrl", "ctrl", 120.0)):
        motor = model.actuator(name).id
        data.ctrl[:] = 0.0
        data.ctrl[motor] = -1e6
        mujoco.mj_forward(model, data)
        moment = np.zeros((model.nu, model.nv))
        mujoco.mju_sparse2dense(moment, data.actuator_moment, data.moment_rownnz,
                                data.moment_rowadr, data.moment_colind)
        row = list(f_max).index(tendon)
        tension = data.actuator_force[motor] * moment[motor, 0] / ten_j[row, 0]
        assert f_max[tendon] == pytest.approx(abs(tension), rel=1e-12)
        assert abs(tension) == pytest.approx(expected)
    assert f_max["bare"] == 600.0
