"""Every PNG the project writes is readable: no two of its texts overlap and none is cut
off at the figure's edge, on every built-in and fixture arm.

Each figure is rendered as the command writes it; at the moment it is saved, every text that
reaches the canvas (labels, titles, tick labels, legend entries, leader-lined annotations) is
collected with matplotlib's own window extents and checked pairwise
(``tests/figure_text.py``, which does not share code with the label placement).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from matplotlib.figure import Figure

from pimbs_calibration.description import builtin_robots, load_robot
from pimbs_cli.main import main
from tests.figure_text import drawn_texts, overlapping_texts, texts_cut_off

ROOT = Path(__file__).resolve().parents[1]
FIXTURE_ARMS = [
    ROOT / "fixtures" / "foreign_arm" / "acme_left_arm.muscles.yaml",
    ROOT / "fixtures" / "lab-board" / "two-link-lab.muscles.yaml",
    ROOT / "fixtures" / "lab-board" / "two-link-odrive.muscles.yaml",
]
ARMS = [*builtin_robots(), *map(str, FIXTURE_ARMS)]
MJCF_ARMS = [str(ROOT / "fixtures" / "mujoco" / name)
             for name in ("planar_2dof.xml", "spatial_3dof.xml")]


def _distinct_names(robots: list[str]) -> list[str]:
    """One arm per set of joint and muscle names: the plots below draw nothing but those
    names and the data, so two arms that share them draw the same texts."""
    seen: dict[tuple, str] = {}
    for robot in robots:
        desc = load_robot(robot)
        seen.setdefault((desc.joints, tuple(m.name for m in desc.muscles)), robot)
    return list(seen.values())


NAMED_ARMS = _distinct_names(ARMS)


@pytest.fixture
def saved(monkeypatch) -> dict[str, list[tuple[str, str]]]:
    """Checks each figure as it is saved: file name -> overlapping text pairs, and
    ("cut off", text) for a text that sticks out of the figure."""
    found: dict[str, list[tuple[str, str]]] = {}
    original = Figure.savefig

    def savefig(self, fname, *args, **kwargs):
        # an atomic write saves into ".NAME.PID.tmp" first
        name = re.sub(r"^\.(.*)\.\d+\.tmp$", r"\1", Path(getattr(fname, "name", fname)).name)
        found[name] = overlapping_texts(self) + [("cut off", t) for t in texts_cut_off(self)]
        assert drawn_texts(self), f"{name}: nothing drawn"
        return original(self, fname, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    return found


def _two_poses(robot: str) -> str:
    """A --pose away from home: a quarter into each joint's range."""
    desc = load_robot(robot)
    lo, hi = desc.joint_range[:, 0], desc.joint_range[:, 1]
    return ",".join(f"{j}={v:.3f}" for j, v in zip(desc.joints, lo + 0.75 * (hi - lo),
                                                   strict=True))


@pytest.mark.parametrize("robot", ARMS + MJCF_ARMS, ids=lambda r: Path(r).name.split(".")[0])
def test_robot_plot_labels_do_not_collide(robot, tmp_path, saved):
    png = tmp_path / "routing.png"
    res = CliRunner().invoke(main, ["robot", robot, "--plot", str(png), "--poses", "5",
                                    "--pose", _two_poses(robot)])
    assert res.exit_code == 0, res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert saved == {"routing.png": []}


def test_the_overlap_check_sees_a_pile_of_labels():
    """The checker is not blind: labels written at one anchor (the old picture) collide,
    and a title wider than the figure is cut off."""
    fig = Figure()
    ax = fig.add_subplot(projection="3d")
    for name in ("m0", "m1", "m2"):
        ax.text(0, 0, 0, name)
    assert len(overlapping_texts(fig)) == 3
    fig.suptitle("a title far too long for a figure of this width " * 3)
    assert texts_cut_off(fig) == [fig._suptitle.get_text()]


@pytest.mark.parametrize("robot", NAMED_ARMS, ids=lambda r: Path(r).name.split(".")[0])
def test_diagnosis_plots_do_not_collide(robot, tmp_path, saved):
    from pimbs_learn.diagnosis.plots import (
        PLOT_FILES,
        _fit_before_after,
        _implied_errors,
        _torque_residuals,
    )

    desc = load_robot(robot)
    joints, muscles = list(desc.joints), [m.name for m in desc.muscles]
    rng = np.random.default_rng(0)
    n = 60
    theta = rng.uniform(desc.joint_range[:, 0], desc.joint_range[:, 1], (n, len(joints)))
    before = rng.normal(0, 2, (n, len(joints)))

    class Data:  # the fields the plot reads from a diagnosis' paired data
        approach = rng.choice([-1, 0, 1], (n, len(muscles)))
        temperature = rng.uniform(24, 40, (n, len(muscles)))
        time = np.linspace(0, 3600, n)

    label = "tendon_friction + tension_offset + joint_offset"
    _torque_residuals(theta, before, before / 20, joints, label, tmp_path / PLOT_FILES[0])
    _implied_errors(rng.normal(0, 5, (n, len(muscles))), Data, muscles,
                    tmp_path / PLOT_FILES[1])
    fit = {"before": 31.0, "after": 1.02, "torque_rms_Nm": {"before": 2.2, "after": 0.0165},
           "length_rms_m": {"before": 7.1e-5, "after": 3.8e-6}}
    _fit_before_after(fit, label, tmp_path / PLOT_FILES[2])
    assert saved == {name: [] for name in PLOT_FILES}


@pytest.mark.parametrize("robot", NAMED_ARMS, ids=lambda r: Path(r).name.split(".")[0])
def test_estimate_plot_does_not_collide(robot, tmp_path, saved):
    from pimbs_learn.estimate import JointAngleReport
    from pimbs_learn.estimate_plot import estimate_figure

    desc = load_robot(robot)
    rng = np.random.default_rng(1)
    n, nj = 40, len(desc.joints)
    measured = rng.uniform(desc.joint_range[:, 0], desc.joint_range[:, 1], (n, nj))
    report = JointAngleReport(
        joints=list(desc.joints), theta=measured + rng.normal(0, 0.01, (n, nj)),
        rms_error_deg=np.full(nj, 0.57), residual_m=np.zeros(n),
        geometric_theta=measured + rng.normal(0, 0.03, (n, nj)),
        geometric_rms_error_deg=np.full(nj, 1.7), joint_range=desc.joint_range,
        range_source="robot description")
    estimate_figure(report, measured, tmp_path / "estimate.png")
    assert saved == {"estimate.png": []}


@pytest.mark.slow
def test_experiment_figures_do_not_collide(tmp_path, saved):
    """The L_eval curves of the two-joint table and of the 5-DOF table (ten methods in one
    legend) and the joint-angle / muscle-length figure, from a 5-epoch run."""
    out = tmp_path / "exp"
    res = CliRunner().invoke(main, ["experiment", "--quick", "--tables", "1,3", "--epochs", "5",
                                    "--seeds", "1", "--n-train", "5", "--n-train", "10",
                                    "--threads", "1", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert saved == {"table1-curves.png": [], "table1-joint-length.png": [],
                     "table3-curves.png": []}


# ----------------------------------------------- pictures of models as the community ships them
def _finger(tmp_path: Path, pairs: int):
    from pimbs_arm.model import ArmModel
    from tests.offset_finger import write_offset_finger

    return ArmModel.load(write_offset_finger(tmp_path, pairs))


def _drawn_lines(fig) -> list[np.ndarray]:
    """(k, 3) points of every 3-D line drawn on ``fig`` (bones and wires; markers alone, as
    at a wire's sites, draw no line)."""
    return [np.array(line.get_data_3d()).T for ax in fig.axes for line in ax.get_lines()
            if line.get_linestyle() not in ("None", "none", "", " ")]


def test_joints_are_drawn_where_mujoco_turns_them(tmp_path):
    """MyoSuite's way: every body at the world origin, each joint at its ``pos=``. The joints
    sit at MuJoCo's own anchors (``xanchor``, computed here independently of PIMBS) and the
    bones run between them; no bone reaches the body frames at the origin."""
    import matplotlib.pyplot as plt
    import mujoco

    from pimbs_arm.picture import routing_figure
    from tests.offset_finger import JOINTS

    arm = _finger(tmp_path, 1)
    theta = np.array([0.5, 0.9, -0.2])
    model = mujoco.MjModel.from_xml_path(str(arm.robot.mjcf_path))
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    assert np.abs(data.xpos[1:]).max() < 1e-12  # the bodies' frames at home: the origin
    data.qpos[:] = theta
    mujoco.mj_kinematics(model, data)
    skeleton = arm.skeleton(theta)
    for j, name in enumerate(JOINTS):
        np.testing.assert_allclose(skeleton.joints[name], data.xanchor[j], atol=1e-12)
    assert np.linalg.norm(data.xanchor[1] - data.xanchor[0]) > 0.09  # a real knuckle-to-pip

    fig = routing_figure(arm, [("given pose", theta)])
    ends = np.array([p for line in _drawn_lines(fig) for p in (line[0], line[-1])])
    for j in range(len(JOINTS)):  # each joint ends a drawn bone
        assert np.linalg.norm(ends - data.xanchor[j], axis=1).min() < 1e-9
    points = np.vstack(_drawn_lines(fig))
    assert np.linalg.norm(points - data.xpos[1], axis=1).min() > 0.05  # nor at a body frame
    plt.close(fig)


def test_pulley_branches_are_drawn_apart_and_wraps_follow_the_surface(tmp_path):
    """The hood splits at two pulleys: three branches, each its own line, none joined to the
    next; with MuJoCo's divisors their drawn lengths add up to MuJoCo's tendon length, which
    only holds if the wire follows the pin's surface between the tangent points."""
    import matplotlib.pyplot as plt

    from pimbs_arm.picture import routing_figure

    arm = _finger(tmp_path, 1)
    theta = np.array([0.3, 1.1, 0.1])
    hood = arm.muscles.index("hood")
    wire = arm.wire_paths(theta)[hood]
    assert len(wire.branches) == 3

    def length(points: np.ndarray) -> float:
        return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())

    drawn = length(wire.branches[0]) + sum(length(b) / 2 for b in wire.branches[1:])
    mujoco_length = arm.backend.kinematics(theta, jacobian=False).length[hood]
    assert abs(drawn - mujoco_length) < 2e-5
    # straight across the wrap instead: millimetres short (the test can tell the difference)
    chords = [b[[0, 1, len(b) - 2, len(b) - 1]] if len(b) > 4 else b for b in wire.branches]
    assert mujoco_length - (length(chords[0]) + sum(length(c) / 2 for c in chords[1:])) > 5e-4

    fig = routing_figure(arm, [("given pose", theta)])
    lines = _drawn_lines(fig)
    for branch in wire.branches:  # each branch is one line of its own
        assert any(len(line) == len(branch) and np.allclose(line, branch) for line in lines)
    for before, after in zip(wire.branches, wire.branches[1:], strict=False):
        for line in lines:  # no segment from one branch's end to the next one's start
            steps = np.stack([line[:-1], line[1:]], axis=1)
            assert not np.any(np.all(np.isclose(steps, [before[-1], after[0]]), axis=(1, 2)))
    plt.close(fig)


def test_forty_muscles_keep_every_text_on_the_figure(tmp_path):
    """43 tendons (a hand has 39): one legend entry each, beside the panel and wholly on the
    figure; labels only where they fit: no text overlaps another or sticks out."""
    import matplotlib.pyplot as plt

    from pimbs_arm.picture import routing_figure

    arm = _finger(tmp_path, 7)
    fig = routing_figure(arm, [("given pose", np.array([0.6, 1.0, 0.1]))])
    (legend,) = fig.legends
    assert [t.get_text() for t in legend.get_texts()][-1] == "hood (board 43)"
    renderer = fig.canvas.get_renderer()
    assert legend.get_window_extent(renderer).x0 >= fig.axes[0].get_window_extent(renderer).x1
    texts = drawn_texts(fig)
    assert texts_cut_off(fig) == [] and overlapping_texts(fig) == []
    assert sum(text in arm.muscles for text, _ in texts) >= 10  # labels where they fit
    plt.close(fig)


def test_a_trunk_of_muscles_is_listed_by_joint(tmp_path):
    """91 muscles: the legend lists the joints (each muscle coloured by the one it turns
    most) rather than a figure-wide list of names; still nothing cut off."""
    import matplotlib.pyplot as plt

    from pimbs_arm.picture import routing_figure
    from tests.offset_finger import JOINTS

    arm = _finger(tmp_path, 15)
    fig = routing_figure(arm, [("home pose", np.zeros(3))])
    (legend,) = fig.legends
    assert [t.get_text() for t in legend.get_texts()] == [
        f"{JOINTS[0]} (31)", f"{JOINTS[1]} (30)", f"{JOINTS[2]} (30)"]
    assert fig.get_figwidth() < 11 and texts_cut_off(fig) == []
    plt.close(fig)


def test_moment_arm_table_fits_the_width_and_keeps_every_value(tmp_path):
    """Cut into blocks of joints to fit 50 columns, the table holds exactly the values of the
    one-block table, each muscle listed in the blocks of the joints it crosses."""
    from pimbs_arm.explain import describe, moment_arm_table
    from pimbs_arm.routing import check_poses, routing_report

    arm = _finger(tmp_path, 2)
    report = routing_report(arm, check_poses(arm, 5))

    def cells(lines: list[str]) -> set[tuple[str, str, str]]:
        found, header = set(), []
        for line in lines:
            words = line.split()
            if words and set(words) <= set(arm.joints):
                header = words
            elif words and words[0] in arm.muscles:
                found |= {(words[0], j, c) for j, c in zip(header, words[1:], strict=True)
                          if c != "-"}
        return found

    wide, narrow = moment_arm_table(arm, report, 1000), moment_arm_table(arm, report, 50)
    assert max(map(len, narrow)) <= 50 < max(map(len, wide))
    assert cells(narrow) == cells(wide) and len(cells(wide)) == 2 * 2 * 3 + 2
    assert sum(line.split()[:1] == ["j3_left0"] for line in narrow) == 1  # its block only
    for line in describe(arm, report, width=60):
        words = line.split()
        assert len(line) <= 60 or max(map(len, words)) > 60 - 8, line
