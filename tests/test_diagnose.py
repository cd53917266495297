"""Mismatch diagnosis, proven blind on recordings where an effect is concealed.

Each case simulates a clean reference and a "real" recording of the same poses with one
effect hidden in it (and, in some, a muscle routing that differs from the model), runs the
diagnosis without telling it anything, and checks that it names the right effect first,
estimates its size, improves the held-out fit — and names nothing on null cases.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_cli.main import main
from pimbs_learn.diagnosis.inputs import DiagnosisInputError
from pimbs_learn.diagnosis.run import diagnose
from pimbs_recording.format import read_recording, write_recording
from pimbs_sim.effects import parse_effect
from pimbs_sim.simulate import simulate

ROBOT = "two-link-4-muscle"


@pytest.fixture(scope="module")
def arm() -> ArmModel:
    return ArmModel.load(ROBOT)


def _write(tmp_path, arm, name, effects=(), n=300, seed=11, map_kind="atl"):
    data, meta = simulate(arm, n, map_kind, seed=seed,
                          effects=tuple(parse_effect(e, seed=seed) for e in effects))
    path = tmp_path / f"{name}.parquet"
    write_recording(path, data, meta)
    return path


# (conceal spec, expected name, parameter check)
CASES = {
    "tendon_friction": ("tendon_friction:0.12", lambda p: all(
        abs(v["mu"] - 0.12) < 0.01 for v in p.values())),
    "tension_offset": ("tension_offset:12,muscles=m2", lambda p: set(p) == {"m2"}
                       and abs(p["m2"]["offset_N"] - 12) < 0.5),
    "thermal_drift": ("thermal_drift:0.6,muscles=m0", lambda p: "m0" in p
                      and abs(p["m0"]["coefficient_N_per_C"] - 0.6) < 0.1),
    "elastic_stiffness": ("elastic_stiffness:0.6", lambda p: all(
        abs(v["stiffness_ratio"] - 0.6) < 0.03 for v in p.values())),
    "joint_offset": ("joint_offset:0.03,joints=elbow_pitch", lambda p: set(p) == {"elbow_pitch"}
                     and abs(p["elbow_pitch"]["offset_rad"] - 0.03) < 0.003),
    "link_mass": ("link_mass:1.3", lambda p: any(
        abs(v["mass_scale"] - 1.3) < 0.05 for v in p.values())),
}


@pytest.mark.parametrize("effect", sorted(CASES))
@pytest.mark.parametrize("routing", [False, True], ids=["same-routing", "other-routing"])
def test_concealed_effect_is_named_sized_and_fit_improves(tmp_path, arm, effect, routing):
    spec, check = CASES[effect]
    ref = _write(tmp_path, arm, "sim")
    hidden = [spec] + (["routing:0.003"] if routing else [])
    real = _write(tmp_path, arm, "real", hidden)
    result, _ = diagnose(real, ref)
    names = [e["name"] for e in result["effects"]]
    assert names and names[0] == effect, (names, result["candidates"])
    assert check(result["effects"][0]["parameters"]), result["effects"][0]["parameters"]
    assert result["fit"]["after"] < 0.9 * result["fit"]["before"]


@pytest.mark.parametrize("routing", [False, True], ids=["same-routing", "other-routing"])
@pytest.mark.parametrize("map_kind", ["atl", "al"])
def test_no_false_alarm_when_real_matches_simulation(tmp_path, arm, routing, map_kind):
    ref = _write(tmp_path, arm, "sim", map_kind=map_kind)
    real = _write(tmp_path, arm, "real", ["routing:0.003"] if routing else [],
                  seed=11, map_kind=map_kind)
    result, _ = diagnose(real, ref)
    assert result["effects"] == [], result["effects"]
    assert result["fit"]["after"] == result["fit"]["before"]


def test_description_instead_of_reference(tmp_path, arm):
    real = _write(tmp_path, arm, "real", ["tension_offset:10,muscles=m1"])
    result, _ = diagnose(real, robot=ROBOT)
    assert result["effects"][0]["name"] == "tension_offset"
    assert result["effects"][0]["muscles"] == ["m1"]
    clean = _write(tmp_path, arm, "clean", seed=12)
    assert diagnose(clean, robot=ROBOT)[0]["effects"] == []


def test_locate_points_at_the_muscle_and_direction(tmp_path, arm):
    ref = _write(tmp_path, arm, "sim")
    real = _write(tmp_path, arm, "real", ["tension_offset:15,muscles=m3"])
    loc = diagnose(real, ref)[0]["location"]
    worst = max(loc["muscles"], key=lambda e: abs(e["vs_reference"]["tension_diff_mean_N"]))
    assert worst["muscle"] == "m3" and worst["vs_reference"]["tension_diff_mean_N"] > 14
    assert loc["summary"]


def test_cli_json_plots_and_corrected_recording(tmp_path, arm):
    ref = _write(tmp_path, arm, "sim")
    real = _write(tmp_path, arm, "real", ["tendon_friction:0.15"])
    out = tmp_path / "d.json"
    corrected = tmp_path / "fixed.parquet"
    r = CliRunner().invoke(main, ["diagnose", str(real), "--reference", str(ref), "--json",
                                  str(out), "--plots", str(tmp_path / "plots"),
                                  "--corrected", str(corrected)])
    assert r.exit_code == 0, r.output
    result = json.loads(out.read_text())
    assert result["effects"][0]["name"] == "tendon_friction"
    # the heading names the muscles its parameters belong to, not the joints it loads
    muscles = result["effects"][0]["muscles"]
    assert muscles and result["effects"][0]["joints"]
    assert f"1. tendon_friction ({', '.join(muscles)})  ΔBIC" in r.output, r.output
    assert {"before", "after"} <= set(result["fit"])
    assert len(list((tmp_path / "plots").glob("*.png"))) == 3
    # the corrected recording obeys the torque balance far better than the raw one
    fixed, raw = read_recording(corrected), read_recording(real)
    def balance(rec):
        G = arm.muscle_jacobian(rec.theta)
        return np.sqrt(np.mean((np.einsum("bmn,bm->bn", G, rec.tension) + rec.tau_gravity)**2))
    assert balance(fixed) < 0.2 * balance(raw)
    assert fixed.meta["corrected_by"] == "pimbs diagnose"


def test_recordings_that_do_not_pair_are_refused(tmp_path, arm):
    ref = _write(tmp_path, arm, "sim", seed=1)
    real = _write(tmp_path, arm, "real", seed=2)
    with pytest.raises(DiagnosisInputError, match="theta_command differs"):
        diagnose(real, ref)
    other = _write(tmp_path, ArmModel.load("left-arm-5dof"), "five", n=40)
    with pytest.raises(DiagnosisInputError, match="different arms"):
        diagnose(other, ref)
    r = CliRunner().invoke(main, ["diagnose", str(real)])
    assert r.exit_code == 1 and "--reference" in r.output


def test_offset_of_a_joint_gravity_cannot_see_is_found_in_the_lengths(tmp_path):
    """A forearm roll barely changes gravity torque; with the routing matching the
    reference, the tied schema sees its zero error in the muscle lengths."""
    arm5 = ArmModel.load("left-arm-5dof")
    ref = _write(tmp_path, arm5, "sim", n=300)
    real = _write(tmp_path, arm5, "real", ["joint_offset:0.04,joints=forearm_yaw"], n=300)
    result, _ = diagnose(real, ref)
    assert "reference" in result["model"]["schema"]
    top = result["effects"][0]
    assert top["name"] == "joint_offset" and top["joints"] == ["forearm_yaw"]
    assert abs(top["parameters"]["forearm_yaw"]["offset_rad"] - 0.04) < 0.004
    assert result["fit"]["after"] < 0.9 * result["fit"]["before"]


def test_real_recording_without_gravity_column_uses_the_references(tmp_path, arm):
    """tau_gravity is nullable (a logger with no joint model): the paired simulation's
    gravity at the same commanded pose stands in."""
    ref = _write(tmp_path, arm, "sim")
    data, meta = simulate(arm, 300, "atl", seed=11,
                          effects=(parse_effect("tension_offset:12,muscles=m0", seed=11),))
    data["tau_gravity"] = np.full_like(data["tau_gravity"], np.nan)
    real = tmp_path / "nogravity.parquet"
    write_recording(real, data, meta)
    assert np.isnan(read_recording(real).tau_gravity).all()
    result, _ = diagnose(real, ref)
    assert result["effects"][0]["name"] == "tension_offset"
    assert result["effects"][0]["muscles"] == ["m0"]
