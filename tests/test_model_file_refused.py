"""A URDF given where a muscle file belongs is named for what it is, in one line; an MJCF is a
robot description by itself, and one without tendons says so in one line."""

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
FILES = {  # what the one line must say
    "arm.urdf": "arm.urdf is a URDF, not a muscle file: write a .muscles.yaml that names it "
                "(urdf: arm.urdf)",
    "arm.xml": "arm.xml: field 'muscles': ",  # an MJCF without spatial tendons
}


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
    assert res.exit_code == 1, res.output
    assert res.output.count("\n") == 1 and "Traceback" not in res.output, res.output
    assert FILES[name] in res.output, res.output
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


def test_an_mjcf_under_another_suffix_is_named_with_the_rename(tmp_path) -> None:
    """MuJoCo reads an MJCF only from a .xml file: the line says so instead of a YAML error."""
    fixture = Path(__file__).resolve().parents[1] / "fixtures" / "mujoco" / "planar_2dof.xml"
    arm = tmp_path / "arm.mjcf"
    arm.write_text(fixture.read_text())
    with pytest.raises(ValueError, match=r"arm.mjcf: .*is an MJCF.*Rename it to arm.xml"):
        load_robot(arm)
    (tmp_path / "arm.xml").write_text(fixture.read_text())
    assert load_robot(tmp_path / "arm.xml").mjcf_path is not None
