"""`pimbs simulate` and `pimbs collect` refuse a muscle file `pimbs robot` rejects, with the
same diagnosis."""

from __future__ import annotations

from pathlib import Path

import yaml
from click.testing import CliRunner

from pimbs_cli.main import main
from tests.test_robot_cli import ACME


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


def test_simulate_refuses_a_joint_no_muscle_turns_one_way(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    raw = yaml.safe_load(ACME.read_text())
    raw["package_path"] = [str(ACME.parent)]
    # beyond about -1 rad the elbow flexor's wire crosses the joint axis and pushes nothing
    raw["joints"][2]["range"] = [-1.3, -0.1]
    path = tmp_path / "acme.muscles.yaml"
    path.write_text(yaml.safe_dump(raw))
    robot = CliRunner().invoke(main, ["robot", str(path)])
    assert robot.exit_code == 1
    said = robot.output.strip().splitlines()[-1]
    before = _files(tmp_path)
    res = CliRunner().invoke(main, ["simulate", "--robot", str(path), "--samples", "5",
                                    "--out", "sim.parquet"])
    assert res.exit_code == 1, res.output
    assert res.output.count("\n") == 1 and "Traceback" not in res.output, res.output
    # the same diagnosis as `pimbs robot`: the joint, the side, how many checked poses
    problem = said[said.index("(l_elbow_pitch"):said.index("); route")]
    assert problem.startswith("(l_elbow_pitch not towards negative angles at ")
    refusal = (f"Error: {path}: some driven joints cannot be turned both ways {problem}); "
               "route a muscle on the missing side or narrow that joint's range; `pimbs robot "
               f"{path}` shows the moment arms and the poses")
    assert refusal == res.output.strip()
    # collect runs the very checks simulate runs: the same line, before any board is touched
    res = CliRunner().invoke(main, ["collect", "--port", "virtual", "--robot", str(path),
                                    "--samples", "5", "--out", "c.parquet"])
    assert res.exit_code == 1 and res.output.strip() == refusal, res.output
    assert _files(tmp_path) == before  # no recording written


def test_simulate_runs_an_arm_pimbs_robot_accepts(tmp_path) -> None:
    out = tmp_path / "ok.parquet"
    assert CliRunner().invoke(main, ["robot", str(ACME)]).exit_code == 0
    res = CliRunner().invoke(main, ["simulate", "--robot", str(ACME), "--samples", "3",
                                    "--out", str(out)])
    assert res.exit_code == 0 and out.exists(), res.output
