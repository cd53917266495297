"""MuJoCo as the true arm behind the simulated boards (`--plant FILE.xml`): real dynamics that
come to rest where the statics say, a plant that differs from its description, a plant that
does not fit it, and the boards reporting what the integrated arm does."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_cli.main import main
from pimbs_hw.mock.mujoco_plant import RING_TARGET_S, MujocoPlant, PlantMismatch, ringing

ARMS = Path(__file__).resolve().parents[1] / "fixtures" / "mujoco"
PLANAR, REAL = ARMS / "planar_2dof.xml", ARMS / "planar_2dof_real.xml"


def _settle(plant: MujocoPlant, max_s: float = 20.0) -> float:
    """Step 0.1 s at a time until the plant says it is at rest; the arm time it took."""
    t = 0.0
    while t < max_s:
        plant.step(0.1)
        t += 0.1
        if plant.settled():
            return t
    raise AssertionError(f"not settled after {max_s} s: qvel {plant.data.qvel}")


def test_dynamics_come_to_rest_at_the_static_equilibrium():
    arm = ArmModel.load(PLANAR)
    plant = MujocoPlant(PLANAR, arm)
    # power-up: motors hold l = 0, the arm hangs straight (no gravity torque at theta = 0)
    np.testing.assert_allclose(plant.state.theta, 0.0, atol=1e-6)
    target = np.array([0.3, -0.4])
    f = arm.tension_distribution(target, 40.0)
    plant.command(("length",) * arm.n_muscles, arm.length(target, f))
    swung = []
    for _ in range(20):  # the first 0.2 s: it swings past its target (real dynamics)
        swung.append(plant.step(0.01).theta.copy())
    assert not plant.settled()
    assert np.abs(np.array(swung)[:, 0] - target[0]).max() > 0.01
    _settle(plant)
    np.testing.assert_allclose(plant.state.theta, target, atol=2e-4)
    np.testing.assert_allclose(plant.state.tension, f, rtol=0.02, atol=0.5)
    np.testing.assert_allclose(plant.state.length, arm.length(target, f), atol=1e-6)
    # tension mode: the board's force loop holds the commanded tensions; the motor length is
    # whatever the tendon and its elastic element need
    plant.command(("tension",) * arm.n_muscles, f)
    _settle(plant)
    np.testing.assert_allclose(plant.state.tension, f, atol=0.05)
    np.testing.assert_allclose(plant.state.theta, target, atol=2e-3)


def test_a_plant_that_differs_from_its_description_rests_elsewhere():
    arm = ArmModel.load(PLANAR)
    target = np.array([0.3, -0.4])
    f = arm.tension_distribution(target, 40.0)
    plant = MujocoPlant(REAL, arm)
    plant.command(("length",) * arm.n_muscles, arm.length(target, f))
    _settle(plant)
    # the real shoulder pulley is bigger and the arm heavier: the description's commands
    # land somewhere else, by a few degrees, not by numerical noise
    miss = np.abs(plant.state.theta - target)
    assert 0.005 < miss.max() < 0.3
    # the real arm's statics (its own MJCF as a description) predict where it rests
    truth = ArmModel.load(REAL).equilibrium("length", arm.length(target, f), theta0=target)
    np.testing.assert_allclose(plant.state.theta, truth.theta, atol=1e-3)


def test_a_plant_that_does_not_fit_the_description_is_one_line(tmp_path):
    arm = ArmModel.load(PLANAR)
    other = tmp_path / "renamed.xml"
    other.write_text(PLANAR.read_text().replace('name="elbow_extensor"', 'name="triceps"'))
    with pytest.raises(PlantMismatch, match="no tendon named elbow_extensor") as err:
        MujocoPlant(other, arm)
    assert str(other) in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(PlantMismatch, match="no hinge joint named shoulder"):
        MujocoPlant(ARMS / "spatial_3dof.xml", arm)


def test_the_boards_report_what_the_mujoco_arm_does():
    """Through the protocol: loadcells read the tendon tension, motor encoders the motor
    length, joint encoders the joint angles of the integrated arm."""
    from pimbs_hw import open_arm

    arm = ArmModel.load(PLANAR)
    target = np.array([0.15, -0.1])
    f = arm.tension_distribution(target, 30.0)
    lengths = arm.length(target, f)
    with open_arm("virtual", PLANAR, speed=5, seed=1,
                  mock_options={"plant": PLANAR, "noise": False}) as (driver, mock):
        assert isinstance(mock.plant, MujocoPlant)
        driver.command("length", lengths)
        t = 0.0
        while mock.settled() and t < 2.0:  # until the boards hand the command to the motors
            driver.dwell(0.02)
            t += 0.02
        assert not mock.settled(), "the boards never passed the length command on"
        t = 0.0
        while not mock.settled() and t < 10.0:
            driver.dwell(0.1)
            t += 0.1
        state = driver.dwell(0.2)
        truth = mock.snapshot()
        assert truth.theta == pytest.approx(target, abs=1e-3)
        assert state.theta == pytest.approx(truth.theta, abs=1e-3)
        assert state.tension == pytest.approx(truth.tension, abs=0.5)
        assert truth.tension == pytest.approx(f, abs=0.03 * f.max())
        assert np.abs(state.length - truth.length).max() <= 1.5 / 108650  # one count
        driver.command("tension", [30.0, 40.0, 30.0, 40.0, 30.0])
        state = driver.dwell(0.3)
        # the board's force loop holds its tension while the arm swings (these tensions do
        # not balance gravity: the elbow ends on its limit)
        assert state.tension == pytest.approx([30, 40, 30, 40, 30], abs=1.0)


def test_collect_refuses_a_body_effect_with_a_plant(tmp_path):
    out = tmp_path / "d.parquet"
    res = CliRunner().invoke(main, ["collect", "--port", "virtual", "--robot", str(PLANAR),
                                    "--plant", str(REAL), "--conceal", "mass:1.2", "-n", "2",
                                    "--out", str(out)])
    assert res.exit_code == 1 and "make that change in the plant file" in res.output
    res = CliRunner().invoke(main, ["collect", "--port", "can0", "--robot", str(PLANAR),
                                    "--plant", str(REAL), "-n", "2", "--out", str(out)])
    assert res.exit_code == 1 and "act on the simulated arm only" in res.output


def test_mockbus_runs_a_mujoco_plant_and_refuses_one_that_does_not_fit():
    res = CliRunner().invoke(main, ["mockbus", "--robot", str(PLANAR), "--plant", str(REAL),
                                    "--port", "pty", "--duration", "0.3"])
    assert res.exit_code == 0, res.output
    assert f"the true arm: {REAL}, integrated by MuJoCo" in res.output
    spatial = ARMS / "spatial_3dof.xml"
    res = CliRunner().invoke(main, ["mockbus", "--robot", str(PLANAR), "--plant", str(spatial),
                                    "--port", "pty", "--duration", "0.3"])
    assert res.exit_code == 1 and res.output.count("\n") == 1
    assert f"--plant {spatial}: no hinge joint named shoulder" in res.output


# One hinge under no gravity, sprung by MuJoCo's own joint spring: a free swing whose decay
# MuJoCo's integration shows, independent of how PIMBS predicts it.
SWING = """
<mujoco model="swing">
  <compiler angle="radian"/>
  <option gravity="0 0 0" timestep="0.0005"/>
  <worldbody>
    <site name="o1" pos="0.03 0 0.1"/><site name="o2" pos="-0.03 0 0.1"/>
    <body name="link">
      <joint name="hinge" type="hinge" axis="0 1 0" range="-0.5 0.5" damping="{damping}"
        stiffness="40" armature="0.002"/>
      <inertial pos="0 0 -0.2" mass="0.8" diaginertia="0.01 0.01 0.001"/>
      <site name="i1" pos="0.03 0 -0.1"/><site name="i2" pos="-0.03 0 -0.1"/>
    </body>
  </worldbody>
  <tendon>
    <spatial name="front"><site site="o1"/><site site="i1"/></spatial>
    <spatial name="back"><site site="o2"/><site site="i2"/></spatial>
  </tendon>
</mujoco>
"""


def _swing(tmp_path: Path, damping: float) -> Path:
    path = tmp_path / f"swing_{damping:g}.xml"
    path.write_text(SWING.format(damping=damping))
    return path


@pytest.mark.parametrize("damping", [0.02, 0.2])
def test_the_predicted_ring_time_is_the_decay_mujoco_integrates(tmp_path, damping):
    import mujoco

    xml = _swing(tmp_path, damping)
    predicted = ringing(xml, ArmModel.load(xml).robot).decay_s
    model = mujoco.MjModel.from_xml_path(str(xml))
    data = mujoco.MjData(model)
    data.qpos[0] = 0.3
    peaks = []  # (t, |θ|) at each turning point of the free swing
    for _ in range(int(2.0 / model.opt.timestep)):
        before = data.qvel[0]
        mujoco.mj_step(model, data)
        if before * data.qvel[0] < 0:
            peaks.append((data.time, abs(data.qpos[0])))
    (t0, a0), (t1, a1) = peaks[1], peaks[-1]
    measured = (t1 - t0) / np.log(a0 / a1)
    assert predicted == pytest.approx(measured, rel=0.03)


def test_a_barely_damped_plant_is_named_before_the_arm_moves(tmp_path):
    calm, ringing_xml = _swing(tmp_path, 0.2), _swing(tmp_path, 0.002)
    robot = ArmModel.load(calm).robot
    assert ringing(calm, robot).note(calm, robot.joints, 5.0) == ""
    assert ringing(calm, robot).calming(robot.joints, 5.0) == {}
    ring = ringing(ringing_xml, robot)
    line = ring.note(ringing_xml, robot.joints, 5.0)
    assert ring.decay_s > 5.0 and str(ringing_xml) in line and "\n" not in line
    assert line.startswith("warning:")
    # the suggested damping, written into the plant, rings no longer than RING_TARGET_S
    suggested = float(ring.suggested[0])
    assert ring.calming(robot.joints, 5.0) == {"hinge": suggested}
    assert f"hinge {suggested:.2g} N·m·s/rad" in line
    fixed = _swing(tmp_path, suggested)
    assert ringing(fixed, robot).decay_s == pytest.approx(RING_TARGET_S, rel=1e-6)
    # by default a run calms the plant and says so; --plant-damping file keeps the warning
    calmed = ring.note(ringing_xml, robot.joints, 5.0, calmed=True)
    assert calmed.startswith("note:") and f"hinge {suggested:.2g} N·m·s/rad" in calmed
    for flags, said in (([], calmed), (["--plant-damping", "file"], line)):
        res = CliRunner().invoke(main, ["mockbus", "--robot", str(calm), "--plant",
                                        str(ringing_xml), "--port", "pty", "--duration", "0.2",
                                        *flags])
        assert res.exit_code == 0 and said in res.output


def test_a_calmed_plant_comes_to_rest_where_its_file_would_ring(tmp_path):
    """The same load step on the barely damped swing: with the calming damping the arm is at
    rest within a pose's settle time; as its file says it still swings then."""
    ringing_xml = _swing(tmp_path, 0.002)
    arm = ArmModel.load(ringing_xml)
    damping = ringing(ringing_xml, arm.robot).calming(arm.robot.joints, 5.0)
    theta = np.array([0.15])
    lengths = arm.length(theta, arm.tension_distribution(theta, 20.0))
    rest = []
    for joint_damping in (damping, None):
        plant = MujocoPlant(ringing_xml, arm, joint_damping=joint_damping, settle_s=0.0)
        assert plant.mj.dof_damping[0] == (damping["hinge"] if joint_damping else 0.002)
        plant.command(("length",) * arm.n_muscles, lengths)
        for _ in range(50):  # 5 s of arm time, a pose's settle timeout
            plant.step(0.1)
        rest.append(plant.settled())
    assert rest == [True, False]


def test_collect_on_a_barely_damped_plant_calms_it_and_records_how(tmp_path):
    """The whole command on the ringing swing: every pose kept, and the recording says which
    joint damping the simulated arm ran with."""
    from pimbs_recording.format import read_recording

    calm, ringing_xml = _swing(tmp_path, 0.2), _swing(tmp_path, 0.002)
    out = tmp_path / "calmed.parquet"
    res = CliRunner().invoke(main, ["collect", "--port", "virtual", "--robot", str(calm),
                                    "--plant", str(ringing_xml), "--samples", "2",
                                    "--mock-speed", "5", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "this run gives the plant's joints damping of hinge" in res.output
    rec = read_recording(out)
    assert rec.n_rows == 2
    want = ringing(ringing_xml, ArmModel.load(calm).robot).suggested[0]
    assert rec.meta["plant_joint_damping"] == {"hinge": pytest.approx(want)}


def test_collect_on_a_mujoco_plant_records_the_plant_not_the_description(tmp_path):
    """A whole collection through the mock bus on MuJoCo's dynamics: every sample settles
    (slack removal waits for the swinging arm to come to rest), and the lengths recorded are
    the plant's, which differs from the description (bigger pulley, moved insertion)."""
    from pimbs_recording.format import read_recording

    out = tmp_path / "real.parquet"
    res = CliRunner().invoke(main, [
        "collect", "--port", "virtual", "--robot", str(ARMS / "planar_2dof.xml"),
        "--plant", str(ARMS / "planar_2dof_real.xml"), "--samples", "3", "--seed", "1",
        "--mock-speed", "5", "--out", str(out)])
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.n_rows == 3 and rec.array("settled").all()
    arm = ArmModel.load(ARMS / "planar_2dof.xml")
    assert np.abs(rec.length - arm.length(rec.theta, rec.tension)).max() > 5e-4


def _with_tendon_friction(tmp_path, newtons: float) -> Path:
    """The planar arm with MuJoCo tendon friction loss on every wire (its own physics)."""
    xml = PLANAR.read_text().replace('<spatial name="shoulder_flexor" width="0.002">',
                                     f'<spatial name="shoulder_flexor" width="0.002" '
                                     f'frictionloss="{newtons}">')
    xml = xml.replace('<spatial name="shoulder_extensor" width="0.002">',
                      f'<spatial name="shoulder_extensor" width="0.002" '
                      f'frictionloss="{newtons}">')
    path = tmp_path / "planar_friction.xml"
    path.write_text(xml)
    return path


def test_tendon_friction_makes_where_the_arm_rests_depend_on_the_way_in(tmp_path):
    """Friction hysteresis: the same length commands, approached from either side, rest at
    two angles with MuJoCo's tendon friction loss, and at one without it."""
    arm = ArmModel.load(PLANAR)
    target = np.array([0.1, 0.0])
    f = arm.tension_distribution(target, 40.0)

    def rest_from(plant: MujocoPlant, side: float) -> float:
        plant.command(("length",) * arm.n_muscles,
                      arm.length(target + [side, 0.0], arm.tension_distribution(
                          target + [side, 0.0], 40.0)))
        _settle(plant)
        plant.command(("length",) * arm.n_muscles, arm.length(target, f))
        _settle(plant)
        return float(plant.state.theta[0])

    def band(xml: Path) -> float:
        return abs(rest_from(MujocoPlant(xml, arm), +0.15) - rest_from(MujocoPlant(xml, arm),
                                                                       -0.15))

    assert band(PLANAR) < 1e-4  # measured 4e-6 rad
    assert band(_with_tendon_friction(tmp_path, 15.0)) > 1e-3  # measured 2.2e-3 rad


def test_collect_settles_on_a_plant_with_tendon_friction(tmp_path):
    from pimbs_recording.format import read_recording

    out = tmp_path / "friction.parquet"
    res = CliRunner().invoke(main, [
        "collect", "--port", "virtual", "--robot", str(PLANAR),
        "--plant", str(_with_tendon_friction(tmp_path, 8.0)), "--samples", "3", "--seed", "1",
        "--mock-speed", "5", "--out", str(out)])
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.n_rows == 3 and rec.array("settled").all()


def test_a_plant_too_coarse_for_its_wires_is_stepped_finer_and_says_so(tmp_path):
    """The series elastic elements PIMBS adds stiffen with load (K(f + 1) N/m): at f_max they
    swing the light swing arm faster than its file's 10 ms step can follow. The plant says
    which step it needs before the arm moves, and integrates with it."""
    from pimbs_hw.mock.mujoco_plant import timestep

    xml = tmp_path / "coarse.xml"
    xml.write_text(SWING.format(damping=0.2).replace('timestep="0.0005"', 'timestep="0.01"'))
    arm = ArmModel.load(xml)
    step = timestep(xml, arm.robot)
    assert step.needed_s < step.file_s == 0.01 and step.step_s <= step.needed_s
    assert step.omega * step.file_s > 2.0  # the file's step is past the stability limit
    note = step.note(xml)
    assert str(xml) in note and "\n" not in note and f"{step.step_s * 1e3:.3g} ms" in note
    plant = MujocoPlant(xml, arm)
    assert plant.mj.opt.timestep == pytest.approx(step.step_s)
    assert plant.at_rest() is None  # as on a real arm, the host judges rest from readings
    f = arm.tension_distribution(np.array([0.2]), 0.8 * arm.f_max[0])
    plant.command(("length",) * 2, arm.length(np.array([0.2]), f))
    _settle(plant)
    assert plant.failure is None  # the joint's own spring, which the description lacks,
    np.testing.assert_allclose(plant.state.theta, [0.2], atol=0.02)  # moves it a little


def test_a_simulation_that_blows_up_says_so_in_one_line(tmp_path, capfd):
    """Stepped coarser than its wires allow, the plant blows up: MuJoCo's own warning is not
    printed, the state before the step is kept, and the collection's stop says the simulated
    arm went unstable and why, not that a loadcell is miswired."""
    from pimbs_hw.collection.link import DriverLink, SimulatedArmFailed
    from pimbs_hw.collection.session import stop_advice

    xml = _swing(tmp_path, 0.2)
    arm = ArmModel.load(xml)
    plant = MujocoPlant(xml, arm)
    plant.mj.opt.timestep = 0.02  # what a file written for muscle actuators might say
    plant._gains()
    f = arm.tension_distribution(np.array([0.2]), 0.9 * arm.f_max[0])
    plant.command(("length",) * 2, arm.length(np.array([0.2]), f))
    for _ in range(50):
        plant.step(0.05)
    assert plant.failure is not None and "went unstable" in plant.failure
    assert "20 ms step" in plant.failure and "timestep" in plant.failure
    assert np.isfinite(plant.state.theta).all() and np.isfinite(plant.state.tension).all()
    assert "Nan, Inf or huge value" not in capfd.readouterr().err

    class Mock:  # what DriverLink asks of the simulated arm behind the boards
        def failure(self):
            return plant.failure

    class Driver:
        class transport:
            port = "virtual:test"

    with pytest.raises(SimulatedArmFailed) as stop:
        DriverLink(Driver(), Mock()).read()
    advice = stop_advice(stop.value)
    assert "went unstable" in advice and "wiring" not in advice and "\n" not in advice


def test_a_static_solve_that_did_not_converge_is_no_rest_position():
    """The quasi-static arm keeps moving toward the last rest position it found and reports
    a solve that did not converge (wires at 1e15 N against a joint limit) as its failure."""
    from types import SimpleNamespace

    from pimbs_hw.mock.plant import Plant

    arm = ArmModel.load("two-link-4-muscle")
    theta = np.array([0.3, -0.2])
    eq = arm.equilibrium("length", arm.h_geom(theta) - 0.035, theta0=theta)
    assert not eq.converged and eq.tension.max() > 1e12  # not a result
    plant = Plant(arm)
    try:
        why = plant._solver._failure(eq)
        assert why is not None and "no rest position" in why and "No board or wire" in why
        assert plant._solver._failure(SimpleNamespace(converged=True, tension=np.ones(4),
                                                      residual=0.0)) is None
        plant.command(("length",) * 4, arm.h_geom(theta) - 0.035)
        for _ in range(1000):  # the solver thread takes its time on a loaded machine
            plant.step(0.01)
            if plant.failure:
                break
            time.sleep(0.01)
        assert plant.failure is not None
        assert plant.state.tension.max() < arm.f_max.max()  # it never took the absurd state
    finally:
        plant.close()
