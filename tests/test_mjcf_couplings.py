"""MJCF joint couplings (``<equality><joint polycoef>``): a follower moves with its leader, as
MuJoCo enforces it; only the independent joints are driven; lengths, the muscle Jacobian and
gravity are MuJoCo's with the coupling applied (checked against MuJoCo's own constraint, and
by finite differences through the chain rule); the MuJoCo plant lets its equality move them.
Also: names MuJoCo leaves to PIMBS never collide with the file's, and an MJCF muscle's
default limits follow its actuator's force."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from pimbs_arm.model import ArmModel
from pimbs_calibration.description import DescriptionError, load_robot
from tests.mujoco_truth import coupled_truth

# Three driven hinges (shoulder, elbow, twist) and three followers: a slide joint following
# the shoulder by a quartic, a hinge following the elbow by a quartic with an offset, and a
# hinge following that follower (a chain). Leaders and followers have non-zero references
# (qpos0), which MuJoCo's polynomial is taken about. The twist's own equality is switched off
# (active="false"): MuJoCo does not apply it, so the twist moves on its own. The equalities
# are as stiff as MyoSuite writes them (MuJoCo's constraints are soft: under load a follower
# lags its coupling by an amount their solimp/solref set).
COUPLED = """
<mujoco model="coupled-arm">
  <compiler angle="radian" autolimits="true"/>
  <option gravity="0 0 -9.81" timestep="0.001"/>
  <default>
    <geom contype="0" conaffinity="0"/>
    <equality solimp="0.9999 0.9999 0.001 0.5 2"/>  <!-- as stiff as MyoSuite's -->
  </default>
  <worldbody>
    <site name="o_front" pos="-0.03 0 0.12"/>
    <site name="o_back" pos="0.03 0 0.12"/>
    <body name="upper_arm">
      <joint name="shoulder" type="hinge" axis="0 1 0" range="-0.6 0.6" ref="0.1"
             damping="1"/>
      <inertial pos="0 0 -0.15" mass="1.0" diaginertia="0.009 0.009 0.0008"/>
      <site name="u_front" pos="-0.03 0 -0.1"/>
      <site name="u_back" pos="0.03 0 -0.1"/>
      <body name="sleeve">
        <joint name="glide" type="slide" axis="0.2 0 1" range="-0.05 0.05" damping="5"/>
        <inertial pos="0 0 -0.2" mass="0.3" diaginertia="1e-3 1e-3 1e-4"/>
        <site name="s_front" pos="-0.025 0 -0.25"/>
        <site name="s_back" pos="0.025 0 -0.25"/>
        <body name="forearm" pos="0 0 -0.3">
          <joint name="elbow" type="hinge" axis="0 1 0" range="-0.7 0.5" ref="-0.05"
                 damping="0.5"/>
          <inertial pos="0 0 -0.1" mass="0.6" diaginertia="0.004 0.004 0.0004"/>
          <site name="f_front" pos="-0.02 0 -0.08"/>
          <site name="f_back" pos="0.02 0 -0.08"/>
          <body name="radius_link" pos="0 0 -0.15">
            <joint name="radius" type="hinge" axis="1 0 0" range="-1 1" ref="0.02"
                   damping="0.2"/>
            <inertial pos="0 0.01 -0.05" mass="0.2" diaginertia="1e-3 1e-3 1e-4"/>
            <site name="r_side" pos="0 0.02 -0.06"/>
            <body name="hand" pos="0 0 -0.1">
              <joint name="wrist" type="hinge" axis="0 1 0" range="-1 1" damping="0.1"/>
              <inertial pos="0.01 0 -0.04" mass="0.15" diaginertia="5e-4 5e-4 5e-5"/>
              <site name="h_front" pos="-0.015 0 -0.05"/>
              <site name="h_back" pos="0.015 0 -0.05"/>
              <body name="finger" pos="0 0 -0.08">
                <joint name="twist" type="hinge" axis="0 0 1" range="-0.5 0.5"
                       damping="0.05"/>
                <inertial pos="0.01 0.01 -0.02" mass="0.05" diaginertia="1e-4 1e-4 1e-5"/>
                <site name="t_a" pos="0.012 0.01 -0.03"/>
                <site name="t_b" pos="-0.01 -0.012 -0.03"/>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <equality>
    <joint name="glide_with_shoulder" joint1="glide" joint2="shoulder"
           polycoef="0.002 0.01 -0.02 0.005 0.001"/>
    <joint name="radius_with_elbow" joint1="radius" joint2="elbow"
           polycoef="0.05 0.4 -0.3 0.2 0.1"/>
    <joint name="wrist_with_radius" joint1="wrist" joint2="radius" polycoef="0 -0.5 0 0 0"/>
    <joint name="twist_off" joint1="twist" joint2="elbow" polycoef="0 1 0 0 0"
           active="false"/>
  </equality>
  <tendon>
    <spatial name="shoulder_front"><site site="o_front"/><site site="u_front"/>
      <site site="s_front"/></spatial>
    <spatial name="shoulder_back"><site site="o_back"/><site site="u_back"/>
      <site site="s_back"/></spatial>
    <spatial name="elbow_front"><site site="s_front"/><site site="f_front"/>
      <site site="h_front"/></spatial>
    <spatial name="elbow_back"><site site="s_back"/><site site="f_back"/>
      <site site="h_back"/></spatial>
    <spatial name="roll"><site site="u_front"/><site site="r_side"/><site site="h_back"/>
      </spatial>
    <spatial name="twist_a"><site site="f_front"/><site site="t_a"/></spatial>
    <spatial name="twist_b"><site site="f_back"/><site site="t_b"/></spatial>
  </tendon>
</mujoco>
"""
FOLLOWERS = ("glide", "radius", "wrist")
POLY = {"glide": ("shoulder", [0.002, 0.01, -0.02, 0.005, 0.001]),
        "radius": ("elbow", [0.05, 0.4, -0.3, 0.2, 0.1]),
        "wrist": ("radius", [0.0, -0.5, 0.0, 0.0, 0.0])}


@pytest.fixture(scope="module")
def coupled(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("coupled") / "coupled.xml"
    path.write_text(COUPLED)
    return path


def _poses(arm: ArmModel, n: int, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.vstack([arm.joint_range.T, rng.uniform(*arm.joint_range.T, (n, arm.n_joints))])


def test_only_the_independent_joints_are_driven(coupled):
    robot = load_robot(coupled)
    assert robot.joints == ("shoulder", "elbow", "twist")  # the twist's equality is off
    assert [c.follower for c in robot.couplings] == ["glide", "radius", "wrist"]  # leaders 1st
    assert robot.locked == ()
    assert [(c.leader, c.equality) for c in robot.couplings] == [
        ("shoulder", "glide_with_shoulder"), ("elbow", "radius_with_elbow"),
        ("radius", "wrist_with_radius")]


def test_lengths_and_jacobians_are_mujocos_with_the_coupling_set(coupled):
    """qpos set per MuJoCo's documented rule (q1 = ref1 + poly(q2 - ref2)) by hand, then
    MuJoCo's own ten_length and ten_J; the Jacobian with respect to the driven joints by the
    chain rule, written out here."""
    arm = ArmModel(load_robot(coupled), check=False)
    model = mujoco.MjModel.from_xml_path(str(coupled))
    data = mujoco.MjData(model)
    jid = {model.joint(i).name: i for i in range(model.njnt)}
    tid = [model.tendon(t).id for t in arm.muscles]
    for theta in _poses(arm, 20):
        data.qpos[:] = model.qpos0
        data.qpos[[model.jnt_qposadr[jid[j]] for j in arm.joints]] = theta
        slope = {}
        for follower in FOLLOWERS:
            leader, c = POLY[follower]
            d = data.qpos[model.jnt_qposadr[jid[leader]]] - model.qpos0[
                model.jnt_qposadr[jid[leader]]]
            data.qpos[model.jnt_qposadr[jid[follower]]] = model.qpos0[
                model.jnt_qposadr[jid[follower]]] + sum(c[k] * d ** k for k in range(5))
            slope[follower] = sum(k * c[k] * d ** (k - 1) for k in range(1, 5))
        mujoco.mj_fwdPosition(model, data)
        J = np.zeros((model.ntendon, model.nv))
        mujoco.mju_sparse2dense(J, data.ten_J, model.ten_J_rownnz, model.ten_J_rowadr,
                                model.ten_J_colind)
        col = {j: J[tid, model.jnt_dofadr[jid[j]]] for j in jid}
        G = np.stack([col["shoulder"] + slope["glide"] * col["glide"],
                      col["elbow"] + slope["radius"] * (col["radius"]
                                                        + slope["wrist"] * col["wrist"]),
                      col["twist"]], axis=1)
        kin = arm.backend.kinematics(theta)
        np.testing.assert_allclose(kin.length, data.ten_length[tid], rtol=0, atol=1e-12)
        np.testing.assert_allclose(kin.jacobian, G, rtol=0, atol=1e-12)
    # the followers matter: without them the elbow's moment arms would be others
    assert np.abs(G[:, 1] - col["elbow"]).max() > 1e-3


def test_lengths_jacobian_and_gravity_agree_with_the_coupling_mujoco_enforces(coupled):
    arm = ArmModel(load_robot(coupled), check=False)
    model = arm.backend.mj_model
    for theta in _poses(arm, 15, seed=2):
        truth = coupled_truth(model, arm.joints, arm.muscles, theta)
        assert truth.residual < 1e-12
        kin = arm.backend.kinematics(theta)
        np.testing.assert_allclose(kin.length, truth.length, rtol=0, atol=1e-9)
        np.testing.assert_allclose(kin.jacobian, truth.jacobian, rtol=0, atol=1e-9)
        np.testing.assert_allclose(arm.gravity_torque(theta), truth.gravity, rtol=0,
                                   atol=1e-9)


def test_jacobian_and_gravity_are_derivatives_through_the_coupling(coupled):
    """G = dl/dθ and g = dV/dθ, V the gravity potential of the coupled arm, by central
    differences of the lengths and of the potential; g's derivative likewise."""
    arm = ArmModel(load_robot(coupled), check=False)
    h = 1e-6
    for theta in _poses(arm, 5, seed=3)[2:]:
        steps = np.eye(arm.n_joints) * h
        dl = np.stack([(arm.h_geom(theta + e) - arm.h_geom(theta - e)) / (2 * h)
                       for e in steps], axis=1)
        np.testing.assert_allclose(arm.muscle_jacobian(theta), dl, atol=1e-8)
        dv = np.array([(arm.potential_energy(theta + e) - arm.potential_energy(theta - e))
                       / (2 * h) for e in steps])
        np.testing.assert_allclose(arm.gravity_torque(theta), dv, atol=1e-7)
        dg = np.stack([(arm.gravity_torque(theta + e) - arm.gravity_torque(theta - e))
                       / (2 * h) for e in steps], axis=1)
        np.testing.assert_allclose(arm.backend.gravity_derivative(theta), dg, atol=1e-6)


def test_a_locked_leader_holds_its_followers_where_the_equalities_put_them(coupled, tmp_path):
    (tmp_path / "arm.xml").write_text(COUPLED)
    path = tmp_path / "arm.muscles.yaml"
    path.write_text(yaml.safe_dump({"mjcf": "arm.xml", "joints": [{"name": "shoulder"},
                                                                  {"name": "twist"}],
                                    "lock": {"elbow": 0.2}}))
    robot = load_robot(path)
    assert [c.follower for c in robot.couplings] == ["glide"]
    locked = dict(robot.locked)
    d = 0.2 - (-0.05)  # about the elbow's reference
    radius = 0.02 + sum(c * d ** k for k, c in enumerate(POLY["radius"][1]))
    assert locked["elbow"] == 0.2
    assert locked["radius"] == pytest.approx(radius, abs=1e-15)
    assert locked["wrist"] == pytest.approx(-0.5 * (radius - 0.02), abs=1e-15)
    arm = ArmModel(robot, check=False)
    truth = coupled_truth(arm.backend.mj_model, arm.joints, arm.muscles, np.array([0.3, 0.1]),
                          held={"elbow": 0.2})
    np.testing.assert_allclose(arm.backend.kinematics(np.array([0.3, 0.1])).length,
                               truth.length, atol=1e-9)


@pytest.mark.parametrize("change, field, words", [
    ({"joints": [{"name": "radius"}]}, "joints[0].name",
     "'radius' follows 'elbow' through the MJCF's joint equality 'radius_with_elbow'"),
    ({"lock": {"wrist": 0.1}}, "lock.wrist", "moves with the driven joint 'elbow'"),
    ({"joints": [{"name": "shoulder"}], "lock": {"radius": 0.1}}, "lock.radius",
     "Drive or lock its leader 'elbow' instead"),
])
def test_a_follower_is_neither_driven_nor_locked(tmp_path, change, field, words):
    (tmp_path / "arm.xml").write_text(COUPLED)
    path = tmp_path / "arm.muscles.yaml"
    path.write_text(yaml.safe_dump({"mjcf": "arm.xml", **change}))
    with pytest.raises(DescriptionError) as err:
        load_robot(path)
    assert err.value.field == field and words in str(err.value), str(err.value)


@pytest.mark.parametrize("extra, words", [
    ('<joint joint1="wrist" joint2="shoulder" polycoef="0 1 0 0 0"/>',
     "'wrist' is joint1 of two active joint equalities, 'wrist_with_radius' and 'equality"),
    ('<joint joint1="elbow" joint2="wrist" polycoef="0 1 0 0 0"/>', "in a loop"),
])
def test_couplings_pimbs_cannot_resolve_are_one_line(tmp_path, extra, words):
    path = tmp_path / "odd.xml"
    path.write_text(COUPLED.replace("</equality>", extra + "</equality>"))
    with pytest.raises(DescriptionError) as err:
        load_robot(path)
    assert words in str(err.value) and str(path) in str(err.value)
    assert "\n" not in str(err.value)


def test_the_mujoco_plant_moves_the_followers_with_their_leaders(coupled):
    """MuJoCo's own equality constraint stays on in the plant: the followers are neither
    held at their reference nor driven; they track their leaders while the arm swings."""
    from pimbs_hw.mock.mujoco_plant import MujocoPlant

    arm = ArmModel(load_robot(coupled), check=False)
    plant = MujocoPlant(coupled, arm, settle_s=0.0)
    m, d = plant.mj, plant.data
    q = {m.joint(i).name: int(m.jnt_qposadr[i]) for i in range(m.njnt)}
    couplings = {c.follower: c for c in arm.robot.couplings}
    for name in FOLLOWERS:  # placed by the coupling at power-up
        c = couplings[name]
        assert d.qpos[q[name]] == pytest.approx(c.value(d.qpos[q[c.leader]]), abs=1e-12)
    d.qvel[m.jnt_dofadr[m.joint("elbow").id]] = 3.0  # swing the elbow
    start = d.qpos[q["elbow"]]
    plant.step(0.05)
    assert abs(d.qpos[q["elbow"]] - start) > 0.02
    # a soft constraint lags a little while it pulls (MuJoCo's solref time constant) ...
    lag = {n: abs(d.qpos[q[n]] - couplings[n].value(d.qpos[q[couplings[n].leader]]))
           for n in FOLLOWERS}
    assert max(lag.values()) < 1e-2, lag
    moved = abs(d.qpos[q["radius"]] - couplings["radius"].value(start))
    assert moved > 3 * lag["radius"]
    # ... and holds once the arm is at rest
    for _ in range(30):
        plant.step(0.1)
    assert np.abs(d.qvel).max() < 1e-2
    for name in FOLLOWERS:
        c = couplings[name]
        assert d.qpos[q[name]] == pytest.approx(c.value(d.qpos[q[c.leader]]), abs=1e-4)


def test_a_coupled_plant_powers_up_within_its_limits_followers_coupled(coupled, tmp_path):
    """An arm whose zero pose lies outside a joint's limits powers up at the nearest pose
    within them, and the followers of that joint start where their couplings put them there
    (not where θ = 0 would): MuJoCo's equality then has nothing to yank on the first step.
    The timestep check sweeps the same coupled arm."""
    from pimbs_hw.mock.mujoco_plant import MujocoPlant, timestep

    xml = tmp_path / "coupled_elbow_bent.xml"
    bent = COUPLED.replace('range="-0.7 0.5" ref="-0.05"', 'range="0.2 0.5" ref="-0.05"')
    assert bent != COUPLED
    xml.write_text(bent)
    arm = ArmModel(load_robot(xml), check=False)
    plant = MujocoPlant(xml, arm, settle_s=0.0)
    m, d = plant.mj, plant.data
    q = {m.joint(i).name: int(m.jnt_qposadr[i]) for i in range(m.njnt)}
    assert d.qpos[q["elbow"]] == pytest.approx(0.2, abs=1e-12)
    couplings = {c.follower: c for c in arm.robot.couplings}
    for name in FOLLOWERS:
        c = couplings[name]
        assert d.qpos[q[name]] == pytest.approx(c.value(d.qpos[q[c.leader]]), abs=1e-12)
    assert abs(d.qpos[q["radius"]] - couplings["radius"].value(0.0)) > 0.05  # it moved
    step = timestep(xml, arm.robot)
    assert 0 < step.omega < np.inf and step.step_s <= step.file_s
    plant.step(0.05)
    assert plant.failure is None


# Tendons 1 and 3 unnamed, a named tendon called "tendon1" (what MuJoCo's viewer would call
# tendon 1): the generated names must not take it.
UNNAMED = """
<mujoco>
  <worldbody>
    <site name="a" pos="0.03 0 0.1"/><site name="b" pos="-0.03 0 0.1"/>
    <body>
      <joint name="hinge" axis="0 1 0" range="-0.5 0.5"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.02" mass="1"/>
      <site name="a1" pos="0.03 0 -0.1"/><site name="b1" pos="-0.03 0 -0.1"/>
    </body>
  </worldbody>
  <tendon>
    <spatial name="tendon1"><site site="a"/><site site="a1"/></spatial>
    <spatial><site site="b"/><site site="b1"/></spatial>
    <spatial name="front"><site site="a"/><site site="b1"/></spatial>
    <spatial><site site="b"/><site site="a1"/></spatial>
  </tendon>
  <actuator>
    <muscle name="weak" tendon="front" force="5" lengthrange="0.1 0.3"/>
  </actuator>
</mujoco>
"""


def test_generated_names_never_take_a_name_the_file_uses(tmp_path):
    path = tmp_path / "unnamed.xml"
    path.write_text(UNNAMED)
    robot = load_robot(path)
    assert [m.name for m in robot.muscles] == ["tendon1", "tendon1_unnamed", "front", "tendon3"]
    assert len({m.board_id for m in robot.muscles}) == 4


def test_an_mjcf_muscles_default_floor_follows_its_force(tmp_path):
    path = tmp_path / "unnamed.xml"
    path.write_text(UNNAMED)
    floors = {m.name: (m.f_floor, m.f_max) for m in load_robot(path).muscles}
    assert floors["front"] == (pytest.approx(0.25), pytest.approx(5.0))  # f_max / 20
    assert floors["tendon1"] == (10.0, 600.0)  # no actuator: the stated defaults
    # a floor the muscle file sets for every muscle: the message names the muscle, where
    # both limits came from, and how to set them for that muscle alone
    (tmp_path / "arm.xml").write_text(UNNAMED)
    spec = tmp_path / "arm.muscles.yaml"
    spec.write_text(yaml.safe_dump({"mjcf": "arm.xml", "defaults": {"f_floor": 10}}))
    with pytest.raises(DescriptionError) as err:
        load_robot(spec)
    text = str(err.value)
    assert err.value.field == "tendon front.f_floor"
    assert "muscle 'front': its holding floor f_floor 10 N (the defaults of arm.muscles.yaml)" \
        in text
    assert "not below its f_max 5 N (the peak force of muscle actuator 'weak')" in text
    assert "'- {name: front, f_floor: 0.25}'" in text and "take f_floor out of 'defaults'" \
        in text
    assert "muscles[" not in text and "rename" not in text.lower()
