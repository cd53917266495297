"""One recording, one writer: a second `pimbs collect` on a file in use is refused in one
line, and a writer killed with kill -9 leaves no lock that stops the next one."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from pimbs_cli.main import main
from pimbs_recording.format import read_recording
from pimbs_recording.writer_lock import lock_path

PIMBS = Path(sys.executable).with_name("pimbs")
FAST = ["--port", "virtual", "--mock-speed", "20", "--fixed-wait", "0"]


def _files(root: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(root.iterdir()) if p.is_file()}


def _wait_for(check, proc: subprocess.Popen, what: str, timeout: float = 60.0) -> None:
    end = time.monotonic() + timeout
    while not check():
        assert proc.poll() is None, f"the writer ended before {what}"
        assert time.monotonic() < end, f"no {what} after {timeout} s"
        time.sleep(0.01)


def _one_error_line(text: str) -> str:
    lines = [x for x in text.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error: "), text
    return lines[0]


def test_second_collect_on_a_file_in_use_is_refused_and_nothing_is_lost(tmp_path) -> None:
    rec_dir = tmp_path / "rec"
    rec_dir.mkdir()
    out = rec_dir / "same.parquet"
    args = [str(PIMBS), "collect", *FAST, "--samples", "12", "--out", str(out)]
    with open(tmp_path / "first.log", "wb") as log:
        first = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT)
        try:
            _wait_for(lambda: out.exists() and lock_path(out).exists(), first, "first row")
            # (not frozen with SIGSTOP: its watchdog would rightly stop a link silent that
            # long; the test below shows, with a still holder, that a refusal writes nothing)
            second = subprocess.run([*args, "--resume"], capture_output=True, text=True,
                                    timeout=120)
            assert first.poll() is None, "the first writer ended before the second started"
            assert first.wait(timeout=120) == 0, (tmp_path / "first.log").read_text()
        finally:
            if first.poll() is None:
                first.kill()
    assert second.returncode == 1, second.stdout + second.stderr
    line = _one_error_line(second.stdout + second.stderr)
    assert f"{out} is being written by another process (pid {first.pid} on " in line
    assert "choose another --out" in line
    rec = read_recording(out)  # the first writer's samples, all of them, none lost
    np.testing.assert_array_equal(rec.sample, np.arange(12))
    assert not lock_path(out).exists()  # a finished writer leaves no lock file


HOLD = """
import sys, time
from pathlib import Path
from pimbs_recording.writer_lock import writer_lock
with writer_lock(Path(sys.argv[1])):
    print("held", flush=True)
    time.sleep(120)
"""


def test_a_writer_killed_with_kill_9_leaves_no_stale_lock(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "r.parquet"
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(out)], stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        before = _files(tmp_path)
        res = CliRunner().invoke(main, ["collect", *FAST, "--samples", "2", "--out", "r.parquet"])
        assert res.exit_code == 1, res.output
        line = _one_error_line(res.output)
        assert f"r.parquet is being written by another process (pid {holder.pid} on " in line
        assert _files(tmp_path) == before
        os.kill(holder.pid, signal.SIGKILL)
        holder.wait(timeout=30)
    finally:
        if holder.poll() is None:
            holder.kill()
    assert lock_path(out).exists()  # kill -9 leaves the name behind, but no lock on it
    res = CliRunner().invoke(main, ["collect", *FAST, "--samples", "2", "--out", "r.parquet"])
    assert res.exit_code == 0, res.output
    assert read_recording(out).n_rows == 2 and not lock_path(out).exists()
