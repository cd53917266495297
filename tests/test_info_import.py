"""`pimbs info` on an imported log says it has no commanded poses (never "0°" accuracy)."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from pimbs_arm.model import ArmModel
from pimbs_cli.main import main
from pimbs_import.synthetic import LogSpec, write_log


def test_info_on_an_imported_log_has_no_pose_accuracy(tmp_path: Path) -> None:
    log, out = tmp_path / "arm.bag", tmp_path / "imported.parquet"
    write_log(log, ArmModel.load("two-link-4-muscle"), LogSpec(poses=3, seed=1), "ros1")
    res = CliRunner().invoke(main, ["import", str(log), "--robot", "two-link-4-muscle",
                                    "--out", str(out)])
    assert res.exit_code == 0, res.output
    before = out.read_bytes()
    res = CliRunner().invoke(main, ["info", str(out)])
    assert res.exit_code == 0, res.output
    assert "source import" in res.output
    line = next(x for x in res.output.splitlines() if "pose accuracy" in x)
    assert line.strip() == ("pose accuracy  none: no commanded poses (theta_command holds the "
                            "held pose's measured mean (a log has no commands))")
    assert "0°" not in res.output and "rms(θ − θ_command)" not in res.output
    assert out.read_bytes() == before  # info only reads


def test_info_on_a_collection_still_reports_pose_accuracy(tmp_path: Path) -> None:
    out = tmp_path / "c.parquet"
    res = CliRunner().invoke(main, ["collect", "--port", "virtual", "--samples", "2",
                                    "--mock-speed", "20", "--fixed-wait", "0",
                                    "--out", str(out)])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(main, ["info", str(out)])
    assert res.exit_code == 0 and "pose accuracy rms(θ − θ_command)" in res.output, res.output
