"""A joint spring is not among the effects the diagnosis names: what it explains is not
given another name.

MuJoCo is the plant (its own joint ``stiffness`` and ``springref``), PIMBS's simulator the
reference, and the diagnosis gets the robot description, which has no spring: a cover or
a cable bundle pulling a joint toward one angle, as on a real arm. The population's arm
drawn from seed 11 (two joints, six muscles) is small enough to record in seconds.
"""

from __future__ import annotations

import pytest

from pimbs_hw.mock.mujoco_recording import record_plant
from pimbs_learn.diagnosis import confound
from pimbs_learn.diagnosis.run import diagnose
from pimbs_recording.format import write_recording
from pimbs_sim.conditions import write_plant
from pimbs_sim.effects import Effect
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
