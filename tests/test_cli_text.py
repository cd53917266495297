"""What the `pimbs` command says: whole summaries, every option described, one line per bad
input (and the good inputs beside it still served)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from pimbs_cli.main import COMMANDS, main

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"


def _pimbs(*args: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pimbs_cli.main", *args], capture_output=True,
                          text=True, timeout=120, env={**os.environ, **env})


def test_help_lists_every_command_on_one_whole_line():
    run = _pimbs("--help", COLUMNS="80")
    assert run.returncode == 0, run.stderr
    listing = run.stdout.split("Commands:\n", 1)[1].splitlines()
    assert len(listing) == len(COMMANDS), listing  # one line each: nothing wrapped
    for line in listing:
        name = line.split()[0]
        assert line.strip().endswith(COMMANDS[name][1]), line  # the whole summary
        assert len(line) <= 80 and "..." not in line and "…" not in line, line


def test_help_imports_no_command():
    code = ("import sys\nfrom pimbs_cli.main import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in sys.modules if m.startswith('pimbs_cli.') "
            "and m not in ('pimbs_cli.main',)))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().splitlines()[-1] == "[]"


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_option_is_described_in_plain_text(name):
    ctx = main.make_context("pimbs", ["--help"], resilient_parsing=True)
    command = main.get_command(ctx, name)
    undescribed = [p.opts[0] for p in command.params
                   if isinstance(p, click.Option) and not p.help]
    assert undescribed == [], f"pimbs {name}: options without a description: {undescribed}"
    text = CliRunner().invoke(main, [name, "--help"], terminal_width=100).output
    assert "%%" not in text, text  # click prints option help as written


def test_train_help_says_percent_once():
    text = CliRunner().invoke(main, ["train", "--help"], terminal_width=100).output
    assert "80 % of the rows" in " ".join(text.split())


def test_info_summarises_every_good_file_and_refuses_each_bad_one(tmp_path):
    missing, junk = tmp_path / "missing.parquet", tmp_path / "junk.parquet"
    junk.write_text("not a recording")
    good = [FIXTURES / "two_link_sim.parquet", FIXTURES / "other_tool_plain_lists.parquet"]
    run = _pimbs("info", str(missing), str(good[0]), str(junk), str(good[1]))
    assert run.returncode == 1
    for path in good:  # summarised although a bad file came before it
        assert f"{path}\n  robot" in run.stdout, run.stdout
    errors = run.stderr.strip().splitlines()
    assert len(errors) == 2 and all(e.startswith("Error: ") for e in errors), run.stderr
    assert str(missing) in errors[0] and str(junk) in errors[1]
    assert "Traceback" not in run.stderr
    alone = _pimbs("info", str(good[0]))
    assert alone.returncode == 0 and alone.stderr == ""


def test_import_of_a_file_that_is_not_a_bag_is_one_line(tmp_path):
    log = tmp_path / "notes.bag"
    log.write_text("these are my lab notes, not a bag\n")
    run = _pimbs("import", str(log), "--robot", "two-link-4-muscle", "--out",
                 str(tmp_path / "x.parquet"))
    assert run.returncode == 1
    lines = (run.stdout + run.stderr).strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"Error: {log}:"), lines  # no progress
    assert not (tmp_path / "x.parquet").exists()


def test_a_robot_that_is_not_there_is_the_options_error():
    run = _pimbs("scan", "--port", "virtual", "--robot", "two-link-lab.muscles.yaml")
    assert run.returncode == 1
    assert run.stderr.startswith("Error: Invalid value for '--robot': two-link-lab.muscles.yaml"
                                 ": no such built-in robot or muscle file"), run.stderr
    assert "field" not in run.stderr and "current directory" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1
