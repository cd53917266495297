"""A joint spring is not among the effects the diagnosis names: what it explains is not
given another name, and PIMBS's simulator holds one as MuJoCo does.

MuJoCo is the plant (its own joint ``stiffness`` and ``springref``), PIMBS's simulator the
reference, and the diagnosis gets the robot description, which has no spring: a cover or
a cable bundle pulling a joint toward one angle, as on a real arm. The population's arm
drawn from seed 11 (two joints, six muscles) is small enough to record in seconds.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from pimbs_hw.mock.mujoco_recording import record_plant
from pimbs_learn.diagnosis import confound
from pimbs_learn.diagnosis.report import text_report
from pimbs_learn.diagnosis.run import diagnose
from pimbs_learn.diagnosis.select import P_VALUE
from pimbs_recording.format import write_recording
from pimbs_sim.conditions import write_plant
from pimbs_sim.effects import Effect, parse_effect
from pimbs_sim.population import make_arm
from pimbs_sim.simulate import simulate

SEED, ROWS = 11, 120
REST = 0.1  # rad: the spring pulls the first joint toward this angle


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    root = tmp_path_factory.mktemp("sprung")
    spec = make_arm(SEED, "mujoco", root / "arm", ROWS)
    data, meta = simulate(spec.load(), ROWS, "atl", seed=SEED, noise_seed=SEED + 7)
    write_recording(root / "reference.parquet", data, meta)
    # a rate that moves the first joint's torque as much as gravity does over its range
    rate = spec.params["gravity_bound"][0] / spec.params["joints"][0]["half_range"]
    return spec, root, rate


def test_pimbs_simulator_holds_a_joint_spring_as_mujoco_pulls_one(arm):
    """The torque the muscles hold on PIMBS's simulator with ``joint_spring`` concealed is
    MuJoCo's own on the plant file with that joint's ``stiffness`` and ``springref``:
    gravity (``qfrc_bias`` at rest) less the spring's pull (``qfrc_passive``)."""
    import mujoco

    spec, root, rate = arm
    plant = write_plant(spec.mjcf, ({"name": "plant_joint_stiffness", "magnitude": rate,
                                     "joints": [spec.joints[0]], "springref": REST},),
                        root / "sprung-oracle.xml")
    model = mujoco.MjModel.from_xml_path(str(plant))
    data = mujoco.MjData(model)
    joints = [model.joint(name) for name in spec.joints]
    described = spec.load()
    sprung = parse_effect(f"joint_spring:{rate},joints={spec.joints[0]},rest={REST}"
                          ).physics(described)
    rng = np.random.default_rng(0)
    lo, hi = described.joint_range[:, 0], described.joint_range[:, 1]
    for theta in rng.uniform(lo, hi, (5, len(joints))):
        data.qpos[:] = 0.0
        for j, q in zip(joints, theta, strict=True):
            data.qpos[j.qposadr[0]] = q
        mujoco.mj_forward(model, data)
        held = np.array([data.qfrc_bias[j.dofadr[0]] - data.qfrc_passive[j.dofadr[0]]
                         for j in joints])
        # the plant file keeps 6 digits of the rate and the rest angle
        np.testing.assert_allclose(sprung.gravity_torque(theta), held, rtol=1e-5, atol=1e-7)
        step = np.zeros(len(joints))
        step[0] = 1e-6  # the energy the equilibrium descends is the spring's too
        slope = (sprung.potential_energy(theta + step)
                 - sprung.potential_energy(theta - step)) / 2e-6
        assert slope == pytest.approx(held[0], rel=1e-4, abs=1e-6)
    assert described.gravity_torque(theta)[0] != pytest.approx(held[0], rel=1e-3)


def _record(spec, root, name: str, plant, effects=()):
    data, meta, stats = record_plant(spec.load(), plant, ROWS, "atl", seed=SEED,
                                     effects=effects)
    assert not stats.skipped
    path = root / f"{name}.parquet"
    write_recording(path, data, meta)
    return path


def test_a_joint_spring_is_reported_as_one_not_named_as_what_follows_it(arm, monkeypatch):
    spec, root, rate = arm
    plant = write_plant(spec.mjcf, ({"name": "plant_joint_stiffness", "magnitude": rate,
                                     "joints": [spec.joints[0]], "springref": REST},),
                        spec.mjcf.with_name("sprung.xml"))
    real = _record(spec, root, "sprung", plant)
    reference = root / "reference.parquet"

    result, _ = diagnose(real, reference, robot=spec.description, design_poses=0)
    assert result["effects"] == [] and result["ambiguous"] == []
    springs = [u["joint_spring"] for u in result["unexplained"] if "joint_spring" in u]
    assert springs, [u["why"] for u in result["unexplained"]]
    for s in springs:  # the plant's own spring, recovered
        assert s["joint"] == spec.joints[0]
        assert s["rate_Nm_per_rad"] == pytest.approx(rate, rel=0.05)
        assert s["rest_angle_rad"] == pytest.approx(REST, abs=0.03)
    assert result["residual"]["consistent_with_noise"]  # the spring leaves nothing

    # the trap: without asking a spring, the same recording names what follows its pull
    monkeypatch.setattr(confound, "outside_rival", lambda *args: None)
    blind, _ = diagnose(real, reference, robot=spec.description, design_poses=0)
    assert {e["name"] for e in blind["effects"]} & {"tension_gain", "link_mass"}


def test_a_true_gain_keeps_its_name_beside_the_spring_it_is_asked_against(arm):
    spec, root, _ = arm
    gain = Effect("tension_gain", 0.15, muscles=(spec.muscles[0],))  # reads 1.15·f
    real = _record(spec, root, "gain", spec.mjcf, (gain,))
    result, _ = diagnose(real, root / "reference.parquet", robot=spec.description,
                         design_poses=0)
    assert [(e["name"], e["muscles"]) for e in result["effects"]] == [
        ("tension_gain", [spec.muscles[0]])]
    assert not any("joint_spring" in u for u in result["unexplained"])
    assert result["effects"][0]["parameters"][spec.muscles[0]]["gain"] == pytest.approx(
        0.15, abs=0.02)


@pytest.mark.parametrize(("link", "alike"), [("link1", True), ("link2", False)])
def test_a_mass_a_spring_only_matches_keeps_its_name_and_the_spring_is_said(arm, link, alike):
    """A heavier first link moves the first joint's torque by a sine of its angle, which a
    spring follows nearly as well over the few poses of a narrow session: the mass stays
    named (a spring does not take a name it only matches) and the spring is said beside
    it, with the poses that would tell the two apart; collected, they do. A heavier second
    link loads both joints, which no spring at one joint follows."""
    import benchmarks.population_diagnosis as bench
    from pimbs_arm.poses_file import read_pose_plan
    from pimbs_learn.diagnosis.design import design_csv

    spec, root, _ = arm
    heavy = (Effect("link_mass", 1.5, link=link),)

    def session(name: str, plan, map_kind: str):
        paths = []
        for kind, kwargs in (("ref", {"noise_seed": SEED + 7}), ("real", {"effects": heavy})):
            data, meta = simulate(spec.load(), len(plan.poses), map_kind, seed=SEED,
                                  poses=plan, **kwargs)
            paths.append(root / f"{name}-{link}.{kind}.parquet")
            write_recording(paths[-1], data, meta)
        return paths[1], paths[0]

    plan = bench.narrow_plan({"description": spec.description, "seed": SEED}, root)
    real, ref = session("narrow", plan, "al")
    result, _ = diagnose(real, ref, robot=spec.description)
    assert [e["name"] for e in result["effects"]] == ["link_mass"]
    note = result["effects"][0].get("spring_fits_alike")
    assert bool(note) == alike
    if not alike:
        return
    assert note["joint"] == spec.joints[0] and note["rate_Nm_per_rad"] > 0
    # beside the spring, the mass adds less than naming asks of one parameter
    assert note["likelihood_ratio_of_effect_given_spring"] < chi2.isf(P_VALUE, 1)
    assert note["separating_poses"]["between"] == ["link_mass", "joint_spring"]
    assert "fits about as well" in text_report(result)
    csv, count = design_csv(result)  # what --poses-out writes
    assert count == len(note["separating_poses"]["poses"]) == 30
    (root / f"poses-{link}.csv").write_text(csv)
    real2, ref2 = session("designed", read_pose_plan(root / f"poses-{link}.csv",
                                                      spec.load()), "atl")
    both, _ = diagnose([real, real2], [ref, ref2], robot=spec.description, design_poses=0)
    assert [e["name"] for e in both["effects"]] == ["link_mass"]
    assert not both["effects"][0].get("spring_fits_alike")  # told apart
