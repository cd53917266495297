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


@pytest.mark.parametrize("robot", ARMS, ids=lambda r: Path(r).name.split(".")[0])
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
