"""Every URDF example-robot-data ships drives a muscle arm, as far as its joints allow.

For each shipped URDF a muscle file is generated (``generated_muscles``: up to two movable
revolute joints, an antagonist pair across each) and the arm model is built from it. A URDF
without a usable joint is skipped with its reason, shown by ``pytest -rs``; the list of such
URDFs is pinned below, so a URDF that stops loading cannot hide among them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_calibration.description import load_robot, reduced_model
from pimbs_cli.main import main
from tests.generated_muscles import MOMENT_ARM, usable_joints, write_muscle_file
from tests.test_shipped_urdf import ROBOTS, URDFS

# URDFs whose joints no muscle pair can drive (no joints, fixed/continuous only, or
# revolute joints without limits): the reason is printed when each is skipped
NO_USABLE_JOINT = {
    "double_pendulum_description/urdf/double_pendulum.urdf",
    "double_pendulum_description/urdf/double_pendulum_continuous.urdf",
    "double_pendulum_description/urdf/double_pendulum_simple.urdf",
    "hector_description/robots/quadrotor_base.urdf",
    "iris_description/robots/iris_simple.urdf",
    "ur_description/urdf/ur3.urdf",
}


def _name(urdf: Path) -> str:
    return urdf.relative_to(ROBOTS).as_posix()


@pytest.mark.parametrize("urdf", URDFS, ids=_name)
def test_shipped_urdf_drives_a_generated_muscle_arm(urdf: Path, tmp_path: Path) -> None:
    muscles = write_muscle_file(urdf, tmp_path)
    if isinstance(muscles, str):
        assert _name(urdf) in NO_USABLE_JOINT, f"{_name(urdf)}: {muscles}"
        pytest.skip(f"{_name(urdf)}: {muscles}")
    assert _name(urdf) not in NO_USABLE_JOINT
    arm = ArmModel(load_robot(muscles))
    joints = [j.name for j in usable_joints(urdf)[0]]
    assert list(arm.joints) == joints and arm.n_muscles == 2 * len(joints)
    middle = arm.joint_range.mean(axis=1)
    G = arm.muscle_jacobian(middle)
    assert G.shape == (2 * len(joints), len(joints))
    for k in range(len(joints)):
        flexor, extensor = G[2 * k, k], G[2 * k + 1, k]
        # each pair pulls its joint both ways with the moment arm it was given
        assert flexor > 0 > extensor, (joints[k], G)
        np.testing.assert_allclose([flexor, -extensor], MOMENT_ARM, rtol=0.2)
        assert np.abs(G[2 * k: 2 * k + 2, :k]).max(initial=0.0) < 1e-9  # only its joint
    assert np.isfinite(arm.gravity_torque(middle)).all()


def test_enough_shipped_urdfs_load_and_every_skip_has_a_reason(tmp_path: Path) -> None:
    results = {_name(u): write_muscle_file(u, tmp_path) for u in URDFS}
    skipped = {n: r for n, r in results.items() if isinstance(r, str)}
    assert set(skipped) == NO_USABLE_JOINT
    assert all(r.startswith("no usable joint (") and len(r) > 20 for r in skipped.values())
    assert len(results) - len(skipped) >= 40


def test_joints_named_like_their_links_keep_their_names(tmp_path: Path) -> None:
    """ANYmal C names each joint like its link; pinocchio's reduction needs them apart."""
    muscles = write_muscle_file(ROBOTS / "anymal_c_simple_description/urdf/anymal.urdf",
                                tmp_path)
    robot = load_robot(muscles)
    assert robot.joints == ("LF_HAA", "LF_HFE")
    assert list(reduced_model(robot).model.names)[1:] == ["LF_HAA", "LF_HFE"]
    assert ArmModel(robot).muscle_jacobian(robot.joint_range.mean(axis=1)).shape == (4, 2)


def test_a_mimic_of_no_joint_is_locked_not_fatal(tmp_path: Path) -> None:
    """The shipped Psyonic hand URDF's finger mimics name a joint that does not exist; those
    fingers are not driven, so they are locked and the arm loads."""
    urdf = ROBOTS / "alex_description/urdf/alex_psyonic_hands.urdf"
    assert "Left_index_q2" in urdf.read_text()
    muscles = write_muscle_file(urdf, tmp_path)
    robot = load_robot(muscles)
    assert "Left_index_q2" in dict(robot.locked)
    res = CliRunner().invoke(main, ["robot", str(muscles), "--poses", "5"])
    assert res.exit_code == 0, res.output
    said = " ".join(res.output.split())  # the lines fit whatever width the terminal has
    assert "(mimic of index_q1, which is not a joint of the URDF)" in said
