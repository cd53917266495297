"""Committed fixture recordings: files written by another tool are read, broken ones are
refused, and the installed `pimbs` command (not the source tree) runs from anywhere."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pimbs_arm.model import ArmModel
from pimbs_learn.diagnosis.run import diagnose
from pimbs_recording.format import RecordingError, read_recording, write_recording
from pimbs_sim.simulate import simulate

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"


def test_other_tools_recording_is_read_with_its_extras():
    rec = read_recording(FIXTURES / "other_tool_plain_lists.parquet")
    assert rec.n_rows == 12 and rec.source == "import" and rec.meta["bag"] == "run_07.bag"
    assert rec.extra_columns == ["operator"]
    assert rec.tension.dtype.name == "float64" and rec.tension.shape == (12, 4)


def test_broken_recording_is_refused_by_name():
    with pytest.raises(RecordingError, match="bad_wrong_length.parquet: column 'tension'"):
        read_recording(FIXTURES / "bad_wrong_length.parquet")


def test_fixture_offset_is_diagnosed():
    result, _ = diagnose(FIXTURES / "two_link_offset.parquet", FIXTURES / "two_link_sim.parquet")
    assert result["effects"][0]["name"] == "tension_offset"
    assert result["effects"][0]["muscles"] == ["m2"]


def _pimbs() -> list[str]:
    exe = shutil.which("pimbs", path=str(Path(sys.executable).parent))
    return [exe] if exe else [sys.executable, "-m", "pimbs_cli.main"]


def test_installed_command_finds_robot_descriptions_from_any_directory(tmp_path):
    """Run outside the checkout, so a non-editable install must carry calibration/robots."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    for robot in ("two-link-4-muscle", "left-arm-5dof"):
        out = tmp_path / f"{robot}.parquet"
        r = subprocess.run([*_pimbs(), "simulate", "--robot", robot, "--samples", "5",
                            "--out", str(out)], cwd=tmp_path, env=env, capture_output=True,
                           text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        r = subprocess.run([*_pimbs(), "info", str(out)], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0 and robot in r.stdout
    bad = subprocess.run([*_pimbs(), "info", str(FIXTURES / "bad_wrong_length.parquet")],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 1 and "Traceback" not in bad.stderr
    assert "column 'tension'" in bad.stderr


def test_install_adds_no_generic_top_level_packages(tmp_path):
    """`cli` and `calibration` are our source folders, installed as pimbs_cli/pimbs_calibration."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    for name in ("cli", "calibration"):
        r = subprocess.run([sys.executable, "-c", f"import {name}"], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=60)
        assert r.returncode != 0 and "ModuleNotFoundError" in r.stderr, name
    r = subprocess.run([sys.executable, "-c", "import pimbs_cli, pimbs_calibration"],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr


# How closely a recomputed column must match the committed one. The simulation runs
# pinocchio, a QP and libm, whose last bits differ between CPUs and BLAS builds, so a float is
# compared within a tolerance far below anything the recording can resolve (sensor noise is
# ~1e-5 m, 0.1 N) but far above rounding (1e-16 relative); everything else is exact.
_TOLERANCE = {  # column: (relative, absolute in the column's unit)
    "theta": (1e-9, 1e-12),          # rad
    "theta_command": (1e-9, 1e-12),  # rad
    "length": (1e-9, 1e-12),         # m
    "tension": (1e-9, 1e-9),         # N
    "temperature": (1e-9, 1e-9),     # °C
    "tau_gravity": (1e-9, 1e-9),     # N·m
}


def _float_values(kind: pa.DataType) -> bool:
    """Whether a column holds floats, as scalars or in any kind of list."""
    while (pa.types.is_list(kind) or pa.types.is_large_list(kind)
           or pa.types.is_fixed_size_list(kind)):
        kind = kind.value_type
    return pa.types.is_floating(kind)


def test_float_columns_are_recognised_in_every_list_type():
    assert _float_values(pa.list_(pa.float64(), 4))  # fixed-size, as the recording writes
    assert _float_values(pa.list_(pa.float32())) and _float_values(pa.large_list(pa.float64()))
    assert not _float_values(pa.list_(pa.int8(), 4)) and not _float_values(pa.int64())


def test_todays_code_writes_the_committed_recording():
    """The recording format is a contract: ``fixtures/two_link_sim.parquet`` was written by
    ``fixtures/make_fixtures.py``; the same call today writes the same columns, values and
    metadata (moving code between packages must not change what is recorded). Integers,
    times, approach directions and metadata are exact; computed floats agree within
    ``_TOLERANCE``, which every CPU meets."""
    data, meta = simulate(ArmModel.load("two-link-4-muscle"), 60, "atl", seed=5)
    meta["created"] = "2026-11-21T00:00:00Z"
    out = FIXTURES / "two_link_sim.parquet"
    with tempfile.TemporaryDirectory() as tmp:
        write_recording(Path(tmp) / "now.parquet", data, meta)
        now = pq.read_table(Path(tmp) / "now.parquet")
    before = pq.read_table(out)
    assert now.schema.equals(before.schema, check_metadata=True)
    assert set(_TOLERANCE) == {f.name for f in before.schema if _float_values(f.type)}
    for name in before.column_names:
        a, b = now[name].to_pylist(), before[name].to_pylist()
        if name not in _TOLERANCE:
            assert a == b, name
        else:
            rtol, atol = _TOLERANCE[name]
            np.testing.assert_allclose(np.array(a, float), np.array(b, float), rtol=rtol,
                                       atol=atol, err_msg=name)
