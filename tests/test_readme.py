"""The README as an outsider follows it: set-up first, in an order that works, and every
measured number in a block that names the benchmark script producing it."""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def _readme_numbers():
    spec = importlib.util.spec_from_file_location(
        "readme_numbers", ROOT / "benchmarks" / "readme_numbers.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("readme_numbers", module)  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _code_blocks(text: str) -> list[tuple[int, str]]:
    """(offset, body) of every fenced code block."""
    return [(m.start(), m[1]) for m in re.finditer(r"```[a-z]*\n(.*?)```", text, re.S)]


def test_every_marked_block_names_an_existing_script():
    rn = _readme_numbers()
    blocks = rn.blocks(README)
    assert len(blocks) >= 10
    # no malformed or unclosed marker
    assert len(re.findall(r"^<!-- numbers:.*$", README, re.M)) == len(blocks)
    assert len(re.findall(r"^<!-- /numbers -->$", README, re.M)) == len(blocks)
    for block in blocks:
        assert block.script.is_file(), f"README block {block.name!r}: no {block.script}"
        assert "<!-- numbers:" not in block.body, f"block {block.name!r} is not closed"
        # a reader sees which command to rerun, not only the hidden marker
        assert f"benchmarks/{block.name}.py" in block.body, f"block {block.name!r}"
    regenerated = {b.name for b in blocks if b.regenerates()}
    assert {"test_count", "cli_startup"} <= regenerated


def test_no_unmarked_sentence_quotes_a_test_count():
    rn = _readme_numbers()
    outside = rn.unmarked(README)
    quoted = re.findall(r"\b\d[\d ,]*\s+(?:passing\s+|unit\s+)?tests\b", outside)
    assert quoted == [], "test counts belong in the test_count block"
    inside = next(b.body for b in rn.blocks(README) if b.name == "test_count")
    assert re.search(r"\*\*\d+ tests\*\*", inside)


def test_regenerating_replaces_only_the_blocks_bodies(monkeypatch):
    """What readme_numbers.py writes: the script's --readme output in place of the block's
    body; markers, the other blocks and every other byte unchanged."""
    rn = _readme_numbers()
    text = ("intro 1\n<!-- numbers:test_count -->\nold count\n<!-- /numbers -->\nmiddle\n"
            "<!-- numbers:bench_train -->\nslow numbers\n<!-- /numbers -->\nend\n")
    ran = []

    def fake_run(cmd, **kwargs):
        ran.append(cmd[1:])
        return subprocess.CompletedProcess(cmd, 0, stdout="The suite has **7 tests**.\n",
                                           stderr="")

    monkeypatch.setattr(rn.subprocess, "run", fake_run)
    new = rn.regenerate(text, None)
    assert new == text.replace("old count\n", "The suite has **7 tests**.\n")
    assert ran == [[str(ROOT / "benchmarks" / "test_count.py"), "--readme"]]


def test_set_up_comes_first_with_the_cpu_torch_note_before_its_commands():
    assert re.findall(r"^## .*", README, re.M)[0] == "## Set-up"
    setup = README.index("## Set-up")
    cpu_note = README.index("download.pytorch.org/whl/cpu")
    main_job = README.index(".venv/bin/pimbs collect --port virtual")
    test_command = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert test_command in README, "the README's test command is not what CI runs"
    assert setup < cpu_note < main_job < README.index(test_command)


def test_environment_is_activated_before_any_bare_command():
    activate = README.index("source .venv/bin/activate")
    bare = [off for off, body in _code_blocks(README)
            if re.search(r"^\s*(pimbs|python) ", body, re.M)
            and "source .venv/bin/activate" not in body]
    assert bare, "the walkthroughs use bare commands"
    assert activate < min(bare)
