"""ArmModel physics: geometry, Jacobian, gravity, tension QP, elasticity and static equilibrium."""

from __future__ import annotations

import itertools
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from pimbs_arm.model import ArmModel, Equilibrium, InfeasiblePoseError, sample_poses
from pimbs_calibration.description import DescriptionError, builtin_robots

ROBOTS = Path(__file__).resolve().parents[1] / "calibration" / "robots"


@pytest.fixture(scope="module", params=builtin_robots())
def arm(request) -> ArmModel:
    return ArmModel.load(request.param)


@pytest.fixture(scope="module")
def two_link() -> ArmModel:
    return ArmModel.load("two-link-4-muscle")


def _poses(arm: ArmModel, n: int, seed: int = 0) -> np.ndarray:
    return sample_poses(arm.joint_range, n, np.random.default_rng(seed))


def test_shapes_and_zero_reference(arm):
    N, M = arm.n_joints, arm.n_muscles
    assert arm.K.shape == (M,) and arm.joint_range.shape == (N, 2)
    np.testing.assert_array_equal(arm.h_geom(np.zeros(N)), np.zeros(M))
    np.testing.assert_array_equal(arm.length(np.zeros(N), np.zeros(M)), np.zeros(M))
    theta = _poses(arm, 3)
    assert arm.h_geom(theta).shape == (3, M)
    assert arm.muscle_jacobian(theta).shape == (3, M, N)
    assert arm.gravity_torque(theta).shape == (3, N)
    assert arm.h_geom(theta).dtype == np.float64


def test_muscle_jacobian_matches_finite_differences(arm):
    eps = 1e-6
    for theta in _poses(arm, 4, seed=1):
        fd = np.stack([(arm.h_geom(theta + eps * e) - arm.h_geom(theta - eps * e)) / (2 * eps)
                       for e in np.eye(arm.n_joints)], axis=1)
        np.testing.assert_allclose(arm.muscle_jacobian(theta), fd, atol=1e-8)


def test_gravity_torque_is_gradient_of_potential(arm):
    eps = 1e-6
    theta = _poses(arm, 1, seed=2)[0]
    fd = [(arm.potential_energy(theta + eps * e) - arm.potential_energy(theta - eps * e))
          / (2 * eps) for e in np.eye(arm.n_joints)]
    np.testing.assert_allclose(arm.gravity_torque(theta), fd, atol=1e-6)


def test_two_link_gravity_matches_closed_form(two_link):
    # Masses and COMs read from the URDF; the arm hangs along -z at theta = 0 and both joints
    # turn about +y, so z_com1 = -c1 cos(q1), z_com2 = -l1 cos(q1) - c2 cos(q1 + q2).
    root = ET.parse(ROBOTS / "two-link-4-muscle.urdf").getroot()
    inertial = {ln.get("name"): ln.find("inertial") for ln in root.iter("link")}
    m1, m2 = (float(inertial[n].find("mass").get("value")) for n in ("upper_arm", "forearm"))
    c1, c2 = (-float(inertial[n].find("origin").get("xyz").split()[2])
              for n in ("upper_arm", "forearm"))
    elbow = next(j for j in root.iter("joint") if j.get("name") == "elbow_pitch")
    l1 = -float(elbow.find("origin").get("xyz").split()[2])
    g0 = 9.81
    for q1, q2 in _poses(two_link, 5, seed=3):
        expected = [m1 * g0 * c1 * np.sin(q1) + m2 * g0 * (l1 * np.sin(q1) + c2 * np.sin(q1 + q2)),
                    m2 * g0 * c2 * np.sin(q1 + q2)]
        np.testing.assert_allclose(two_link.gravity_torque(np.array([q1, q2])), expected,
                                   rtol=1e-12, atol=1e-12)


def test_elasticity_round_trip(arm):
    f = np.linspace(0.0, 600.0, arm.n_muscles)
    dn = arm.stretch(f)
    np.testing.assert_allclose(arm.tension_from_stretch(dn), f, rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(arm.tension_from_stretch(-np.abs(dn) - 1e-3), 0.0)
    theta = _poses(arm, 1)[0]
    np.testing.assert_allclose(arm.length(theta, f), arm.h_geom(theta) - dn)


@pytest.mark.parametrize("f_min", [0.0, 150.0, "vector"])
def test_tension_distribution_balances_gravity(arm, f_min):
    theta = _poses(arm, 5, seed=4)
    if f_min == "vector":
        f_min = np.random.default_rng(5).uniform(10, 300, arm.n_muscles)
    f = arm.tension_distribution(theta, f_min)
    G = arm.muscle_jacobian(theta)
    torque = -np.einsum("bmn,bm->bn", G, f)
    np.testing.assert_allclose(torque, arm.gravity_torque(theta), atol=1e-9)
    assert np.all(f >= np.asarray(f_min) - 1e-9)
    np.testing.assert_allclose(arm.tension_distribution(theta[0], f_min), f[0])


def test_tension_distribution_weighted(two_link):
    theta = np.array([0.3, -0.2])
    W = np.diag([1.0, 1.0, 10.0, 1.0])
    f = two_link.tension_distribution(theta, 20.0, W=W)
    np.testing.assert_allclose(-two_link.muscle_jacobian(theta).T @ f,
                               two_link.gravity_torque(theta), atol=1e-9)


def test_one_sided_joint_refused_at_load_naming_file_and_joint(tmp_path):
    # Only the two shoulder muscles: nothing can turn (or hold) the elbow.
    for name in ("two-link-4-muscle.urdf", "two-link-4-muscle.muscles.yaml"):
        shutil.copy(ROBOTS / name, tmp_path / name)
    path = tmp_path / "two-link-4-muscle.muscles.yaml"
    raw = yaml.safe_load(path.read_text())
    raw["muscles"] = raw["muscles"][:3]  # m3, the only elbow extensor, removed
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(DescriptionError, match="'elbow_pitch': no muscle turns it towards "
                       "negative") as err:
        ArmModel.load(path)
    assert str(path) in str(err.value) and err.value.field == "joints[1]"


def test_tension_ceiling_makes_a_pose_infeasible(arm):
    theta = arm.joint_range.mean(axis=1)
    free = arm.tension_distribution(theta, 250.0)
    assert np.allclose(arm.tension_distribution(theta, 250.0, f_max=free.max() + 1), free)
    with pytest.raises(InfeasiblePoseError, match=arm.joints[0]) as err:
        arm.tension_distribution(theta, 250.0, f_max=free.max() - 1)
    assert str(arm.robot.muscle_path) in str(err.value) and "pimbs robot" in str(err.value)


def _corners(arm: ArmModel) -> np.ndarray:
    return np.array(list(itertools.product(*arm.joint_range)))


def test_statically_feasible_over_range(arm):
    """Gravity can be held everywhere in the sampling range, also with the ATL tension floor."""
    rng = np.random.default_rng(6)
    theta = np.vstack([_corners(arm), sample_poses(arm.joint_range, 300, rng)])
    floors = {
        "zero": 0.0,
        "scalar": rng.uniform(10, 300, (len(theta), 1)),
        "per-muscle": rng.uniform(10, 300, (len(theta), arm.n_muscles)),
    }
    f_max = np.array([m.f_max for m in arm.robot.muscles])
    for name, f_min in floors.items():
        f = arm.tension_distribution(theta, f_min)
        assert np.all(f < f_max), f"{arm.robot.name} f_min {name}: max tension {f.max():.0f} N"


def _qp_state(arm: ArmModel, seed: int, f_min: float):
    theta = _poses(arm, 1, seed=seed)[0]
    f = arm.tension_distribution(theta, f_min)
    return theta, f, arm.length(theta, f)


def _assert_equilibrium(eq: Equilibrium, theta, f):
    assert eq.converged
    np.testing.assert_allclose(eq.theta, theta, atol=1e-6)
    np.testing.assert_allclose(eq.tension, f, rtol=1e-3, atol=1e-3)


@pytest.mark.parametrize("seed,f_min", [(10, 0.0), (11, 50.0), (12, 280.0)])
def test_equilibrium_inverts_qp_in_length_mode(arm, seed, f_min):
    theta, f, length = _qp_state(arm, seed, f_min)
    for theta0 in (None, theta + 0.05):
        eq = arm.equilibrium("length", length, theta0=theta0)
        _assert_equilibrium(eq, theta, f)
        np.testing.assert_array_equal(eq.length, length)
        assert eq.residual < 1e-6


def test_equilibrium_mixed_length_and_tension(arm):
    theta, f, length = _qp_state(arm, 13, 100.0)
    mode = np.array(["length", "tension"] * (arm.n_muscles // 2))
    command = np.where(mode == "length", length, f)
    eq = arm.equilibrium(mode, command)
    _assert_equilibrium(eq, theta, f)
    np.testing.assert_allclose(eq.length, length, atol=1e-9)


def test_slack_muscle_reads_zero(arm):
    theta, f, length = _qp_state(arm, 14, 100.0)
    command = length.copy()
    command[0] += 0.05  # paid out 5 cm: the wire goes slack
    eq = arm.equilibrium("length", command, theta0=theta)
    assert eq.converged and eq.tension[0] == 0.0
    assert eq.length[0] == command[0]
    assert eq.residual < 1e-6


def test_all_slack_arm_hangs_at_rest(two_link):
    eq = two_link.equilibrium("length", np.full(4, 0.1), theta0=np.array([0.3, -0.3]))
    assert eq.converged
    np.testing.assert_allclose(eq.theta, 0.0, atol=1e-6)
    np.testing.assert_array_equal(eq.tension, 0.0)


def test_equilibrium_stops_at_joint_limit(two_link):
    # Lengths for a pose beyond the URDF limit: the arm rests on the limit.
    beyond = np.array([1.05, 0.0])
    f = np.full(4, 50.0)
    eq = two_link.equilibrium("length", two_link.length(beyond, f))
    assert eq.converged
    assert eq.theta[0] == pytest.approx(two_link.joint_limits[0, 1])
    assert eq.residual > 1e-3


def test_equilibrium_rejects_bad_input(two_link):
    with pytest.raises(ValueError, match="mode"):
        two_link.equilibrium(["length", "force", "length", "length"], np.zeros(4))
    with pytest.raises(ValueError, match="command"):
        two_link.equilibrium("length", np.zeros(3))


def test_sample_poses_in_range(arm):
    theta = _poses(arm, 200)
    assert theta.shape == (200, arm.n_joints)
    assert np.all(theta >= arm.joint_range[:, 0]) and np.all(theta <= arm.joint_range[:, 1])


def test_length_hessian_matches_finite_differences(arm):
    # The equilibrium solver's Newton steps rely on this curvature term being exact.
    rng = np.random.default_rng(7)
    theta, weight, eps = _poses(arm, 1, seed=7)[0], rng.uniform(0, 300, arm.n_muscles), 1e-6
    fd = np.stack([(arm.muscle_jacobian(theta + eps * e) - arm.muscle_jacobian(theta - eps * e)).T
                   @ weight / (2 * eps) for e in np.eye(arm.n_joints)], axis=1)
    np.testing.assert_allclose(arm.backend.length_hessian(theta, weight), fd, atol=1e-7)


ACME = Path(__file__).resolve().parents[1] / "fixtures/foreign_arm/acme_left_arm.muscles.yaml"


def test_via_points_that_meet_give_numbers_not_warnings():
    """Two via points on different links meet where a wire passes through its joint's axis
    (ACME's shoulder flexor with the shoulder rolled by -π): that segment has length 0 and
    no direction. Lengths, Jacobian and Hessian stay finite and right, with no warning."""
    arm = ArmModel.load(ACME)
    backend = arm.backend
    theta = np.array([0.0, -np.pi, -0.5])
    with np.errstate(all="raise"):  # a 0/0 anywhere in these numerics is an error here
        kin = backend.kinematics(theta)
        hessian = backend.length_hessian(theta, np.full(arm.n_muscles, 50.0))
        assert np.isfinite(arm.equilibrium("length", arm.length(theta, np.full(
            arm.n_muscles, 20.0)), theta0=theta).theta).all()
    assert (kin.cache.seg_len == 0).any(), "the pose no longer makes two via points meet"
    assert np.isfinite(kin.jacobian).all() and np.isfinite(hessian).all()
    # the length is the sum of the straight segments between the via points as placed
    paths = [wire.attachments for wire in backend.wire_paths(theta)]
    want = [np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in paths]
    np.testing.assert_allclose(kin.length, want, rtol=1e-12, atol=1e-15)
    # the muscles whose via points meet get the middle of their one-sided derivatives;
    # every other muscle's Jacobian is what it is a little away from there
    meet = np.unique(backend._seg_owner[kin.cache.seg_len == 0])
    assert "sh_flexor" in [arm.muscles[i] for i in meet]
    step = np.array([0.0, 1e-7, 0.0])
    before, after = (backend.kinematics(theta - step).jacobian,
                     backend.kinematics(theta + step).jacobian)
    np.testing.assert_allclose(kin.jacobian[meet], (before[meet] + after[meet]) / 2, atol=1e-6)
    others = np.setdiff1d(np.arange(arm.n_muscles), meet)
    np.testing.assert_allclose(kin.jacobian[others], after[others], atol=1e-6)


def test_an_arm_resting_where_a_wire_crosses_its_joint_axis_is_at_rest():
    """Where a wire passes through its joint's axis, its length has a corner in the joint
    angle (the moment arm flips sign), and so has the static energy: the gradient never
    vanishes at a rest position there. The commands a collection sent the acme arm (its
    elbow offset by 0.03 rad) come to rest on the elbow flexor's and the biceps' corner,
    and the solve must say so instead of "no rest position", which stopped the collection
    at its 52nd pose."""
    from pimbs_arm.equilibrium import _mode_mask, _Problem

    arm = ArmModel.load(ACME)
    modes = ["tension", "length", "tension", "length", "tension", "tension", "length"]
    values = np.array([103.0, -0.004473078693051081, 81.75, -0.0006258628624022089, 64.75,
                       55.5, -0.028596410492406812])
    eq = arm.equilibrium(modes, values, theta0=np.array([0.0838269, 0.1009200, -1.0241009]))
    assert eq.converged and eq.residual > 0.1  # a corner: no zero gradient to find
    step = np.array([0.0, 0.0, 1e-6])
    slope_below = (arm.h_geom(eq.theta) - arm.h_geom(eq.theta - step)) / 1e-6
    slope_above = (arm.h_geom(eq.theta + step) - arm.h_geom(eq.theta)) / 1e-6
    flips = [arm.muscles[j] for j in np.flatnonzero(slope_below * slope_above < 0)]
    assert {"el_flexor", "biceps"} <= set(flips)
    problem = _Problem(arm, _mode_mask(modes, arm.n_muscles), values)
    rest = problem.evaluate(eq.theta).energy
    for k in range(arm.n_joints):
        for d in (-1e-5, 1e-5):
            moved = eq.theta.copy()
            moved[k] += d
            assert problem.evaluate(moved).energy >= rest
    # a pose off the corner is no rest position the probe would accept
    off = problem.evaluate(eq.theta + np.array([0.0, 0.0, 1e-3]))
    assert off.energy > rest
