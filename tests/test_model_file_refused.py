"""A URDF or MJCF given where a muscle file belongs is named for what it is, in one line."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from pimbs_calibration.description import NotAMuscleFileError, load_robot
from pimbs_calibration.file_kind import model_file_kind
from pimbs_cli.main import main
from tests.test_shipped_urdf import PANDA

MJCF = """<?xml version="1.0"?>
<!-- an arm, as a MuJoCo model -->
<mujoco model="arm">
  <worldbody><body name="upper"><joint name="shoulder"/><geom size="0.1"/></body></worldbody>
</mujoco>
"""
FILES = {"arm.urdf": ("a URDF", None), "arm.xml": ("a MuJoCo model (MJCF)", MJCF)}


@pytest.fixture
def workdir(tmp_path, monkeypatch) -> Path:
    """The shipped Panda URDF as arm.urdf, an MJCF as arm.xml, a recording as data.parquet."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "arm.urdf").write_bytes(PANDA.read_bytes())
    (tmp_path / "arm.xml").write_text(MJCF)
    res = CliRunner().invoke(main, ["simulate", "--samples", "12", "--out", "data.parquet"])
    assert res.exit_code == 0, res.output
    return tmp_path


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


@pytest.mark.parametrize("name", FILES)
@pytest.mark.parametrize("args", [
    ["robot", "{f}"],
    ["simulate", "--robot", "{f}", "--samples", "3", "--out", "sim.parquet"],
    ["collect", "--port", "virtual", "--robot", "{f}", "--samples", "2", "--out", "c.parquet"],
    ["train", "data.parquet", "--robot", "{f}", "--epochs", "1"],
], ids=lambda a: a[0] if isinstance(a, list) else a)
def test_a_model_file_for_a_muscle_file_is_one_line(workdir, name, args) -> None:
    before = _files(workdir)
    res = CliRunner().invoke(main, [a.format(f=name) for a in args])
    kind = FILES[name][0]
    assert res.exit_code == 1, res.output
    assert res.output.count("\n") == 1 and "Traceback" not in res.output, res.output
    assert f"{name} is {kind}, not a muscle file: write a .muscles.yaml that names it " \
           f"(urdf: {name})" in res.output
    assert _files(workdir) == before  # nothing written, nothing changed


def test_kinds_are_told_from_the_content_not_only_the_name(tmp_path) -> None:
    urdf = tmp_path / "arm.yaml"
    urdf.write_text('\ufeff<?xml version="1.0"?>\n<!-- x: y -->\n<robot name="a"/>\n')
    assert model_file_kind(urdf) == "a URDF"
    with pytest.raises(NotAMuscleFileError, match="arm.yaml is a URDF, not a muscle file"):
        load_robot(urdf)
    sdf = tmp_path / "arm.model"
    sdf.write_text("<sdf version='1.7'><model name='a'/></sdf>")
    assert model_file_kind(sdf) == "an SDF model"
    xacro = tmp_path / "arm.urdf.xacro"
    xacro.write_text('<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="a"/>')
    assert model_file_kind(xacro) == "a xacro file"
    muscles = tmp_path / "arm.muscles.yaml"
    muscles.write_text("robot: a  # <robot> in a comment\n")
    assert model_file_kind(muscles) is None
