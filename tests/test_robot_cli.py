"""`pimbs robot`: what a description means, the both-ways check, and the routing picture."""

from __future__ import annotations

from pathlib import Path

import yaml
from click.testing import CliRunner

from pimbs_cli.main import main

ACME = Path(__file__).resolve().parents[1] / "fixtures" / "foreign_arm" / \
    "acme_left_arm.muscles.yaml"


def test_explains_joints_muscles_moment_arms_and_draws(tmp_path):
    png = tmp_path / "acme.png"
    res = CliRunner().invoke(main, ["robot", str(ACME), "--plot", str(png), "--pose",
                                    "l_shoulder_pitch=-0.5,l_elbow_pitch=-0.6", "--poses", "50"])
    assert res.exit_code == 0, res.output
    out = res.output
    assert "driven joints (3" in out and "locked joints (5" in out
    assert "l_wrist_roll           continuous at 0.5" in out
    assert "l_gripper_mimic" in out and "(mimic of l_gripper)" in out
    assert "sh_flexor" in out and "   11 " in out  # board id
    assert "total mass 11.48 kg" in out  # every <mass> of the URDF (kg)
    # the elbow flexor turns the elbow negative, the extensor positive, over the whole range
    flexor = next(line for line in out.splitlines() if line.strip().startswith("el_flexor ")
                  and ".." in line)
    assert flexor.split()[-1].startswith("-") and flexor.split()[1] == "-"
    assert out.count("ok at all 59 poses") == 3  # centre + 8 corners + 50 random
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    res = CliRunner().invoke(main, ["robot", str(ACME), "--plot", str(png)])
    assert res.exit_code == 1 and "--force" in res.output


def test_a_joint_that_cannot_be_turned_both_ways_is_shown_with_its_poses(tmp_path):
    raw = yaml.safe_load(ACME.read_text())
    raw["package_path"] = [str(ACME.parent)]
    # beyond about -1 rad the elbow flexor's wire crosses the joint axis and pushes nothing
    raw["joints"][2]["range"] = [-1.3, -0.1]
    path = tmp_path / "acme.muscles.yaml"
    path.write_text(yaml.safe_dump(raw))
    res = CliRunner().invoke(main, ["robot", str(path), "--poses", "100"])
    assert res.exit_code == 1
    assert "l_elbow_pitch          FAILS at" in res.output
    assert "nothing turns it towards negative angles" in res.output
    assert f"Error: {path}: some driven joints cannot be turned both ways" in res.output
    assert "Traceback" not in res.output


def test_bad_pose_is_one_line():
    res = CliRunner().invoke(main, ["robot", "two-link-4-muscle", "--pose", "wrist=1"])
    assert res.exit_code == 1 and "'wrist' is not a driven joint" in res.output
