"""A joint spring is not among the effects the diagnosis names: what it explains is not
given another name.

MuJoCo is the plant (its own joint ``stiffness`` and ``springref``), PIMBS's simulator the
reference, and the diagnosis gets the robot description, which has no spring: a cover or
a cable bundle pulling a joint toward one angle, as on a real arm. The population's arm
drawn from seed 11 (two joints, six muscles) is small enough to record in seconds.
"""

from __future__ import annotations

import pytest
from scipy.stats import chi2

from pimbs_hw.mock.mujoco_recording import record_plant
from pimbs_learn.diagnosis import confound
from pimbs_learn.diagnosis.report import text_report
from pimbs_learn.diagnosis.run import diagnose
from pimbs_learn.diagnosis.select import P_VALUE
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


@pytest.mark.parametrize(("link", "alike"), [("link1", True), ("link2", False)])
def test_a_mass_a_spring_only_matches_keeps_its_name_and_the_spring_is_said(arm, link, alike):
    """A heavier first link moves the first joint's torque by a sine of its angle, which a
    spring follows nearly as well over the few poses of a narrow session: the mass stays
    named (a spring does not take a name it only matches) and the spring is said beside
    it. A heavier second link loads both joints, which no spring at one joint follows."""
    import benchmarks.population_diagnosis as bench

    spec, root, _ = arm
    plan = bench.narrow_plan({"description": spec.description, "seed": SEED}, root)
    n, paths = len(plan.poses), []
    for name, kwargs in (("narrow-ref", {"noise_seed": SEED + 7}),
                         ("narrow-heavy", {"effects": (Effect("link_mass", 1.5, link=link),)})):
        data, meta = simulate(spec.load(), n, "al", seed=SEED, poses=plan, **kwargs)
        paths.append(root / f"{name}-{link}.parquet")
        write_recording(paths[-1], data, meta)
    result, _ = diagnose(paths[1], paths[0], robot=spec.description, design_poses=0)
    assert [e["name"] for e in result["effects"]] == ["link_mass"]
    note = result["effects"][0].get("spring_fits_alike")
    assert bool(note) == alike
    if alike:
        assert note["joint"] == spec.joints[0] and note["rate_Nm_per_rad"] > 0
        # beside the spring, the mass adds less than naming asks of one parameter
        assert note["likelihood_ratio_of_effect_given_spring"] < chi2.isf(P_VALUE, 1)
        assert "fits about as well" in text_report(result)
