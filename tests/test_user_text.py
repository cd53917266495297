"""User-facing text speaks to a user, not about how the project was made.

README, every Markdown document, every command's ``--help`` and every message string in the
code must not mention issue numbers, work sessions, a brief, lent machines or the people who
wrote it: those words mean nothing to someone who just cloned the repository. Lab notebooks
may date their entries (a date says when something was run); they may not cite issues.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from pimbs_cli.main import main

ROOT = Path(__file__).resolve().parents[1]
SOURCE_DIRS = ["cli", "calibration", "pimbs_arm", "pimbs_recording", "pimbs_sim", "pimbs_hw",
               "pimbs_import", "pimbs_learn"]
HISTORY = re.compile(
    r"\bissues?\b"                     # "issue 9", "the bar"
    r"|\bsessions?\s*#?\d+"            # "session 19"
    r"|\bsessions\b|\bthis session\b"  # the work sessions that built it
    r"|\bthe brief\b|\bbrief's\b"
    r"|\blent\b|\bthis task\b"         # "no GPU was lent to this task"
    r"|\bengineers?\b"
    r"|(?<![\w&/])#\d+\b",             # "#21"
    re.I)


def _hits(text: str) -> list[str]:
    """Each offending phrase with some context."""
    return [text[max(m.start() - 30, 0):m.end() + 30].replace("\n", " ")
            for m in HISTORY.finditer(text)]


def _documents() -> list[Path]:
    """The project's own documents: hidden folders (caches, the venv, git) and build output
    are tools' files, and appear or vanish between runs, so the test set stays the same."""
    def ours(parts: tuple[str, ...]) -> bool:
        return not any(part.startswith(".") or part in {"build", "pimbs.egg-info"}
                       for part in parts[:-1])
    return sorted(p for p in ROOT.rglob("*.md") if ours(p.relative_to(ROOT).parts))


def test_the_pattern_catches_history_and_spares_the_domain():
    for bad in ("Default of `pimbs train` (issue 9).", "seeds 5–9 were added in session 18",
                "no GPU was lent to this task", "the brief's \"about a minute\"", "see #21",
                "other engineers' jobs", "the issue's bar is 1.05×"):
        assert _hits(bad), bad
    for fine in ("a loadcell zeroed at the start of a session", "Ort::Session session(env)",
                 "#include <onnxruntime_cxx_api.h>", "## 8. Where the error grows (2026-11-23)",
                 "a new host session", "issued"):
        assert not _hits(fine), fine


@pytest.mark.parametrize("path", _documents(), ids=lambda p: str(p.relative_to(ROOT)))
def test_documents_have_no_project_history(path):
    assert _hits(path.read_text()) == [], path


def test_help_of_every_command_has_no_project_history():
    runner = CliRunner()
    ctx = main.make_context("pimbs", ["--help"], resilient_parsing=True)
    names = main.list_commands(ctx)
    assert {"collect", "train", "diagnose", "robot", "import"} <= set(names)
    found = {}
    for args in [["--help"], *([name, "--help"] for name in names)]:
        res = runner.invoke(main, args)
        assert res.exit_code == 0, (args, res.output)
        if _hits(res.output):
            found[" ".join(args)] = _hits(res.output)
    assert found == {}


def _message_strings(path: Path) -> list[str]:
    """String constants of a module (f-string parts included), docstrings of plain functions
    and modules left out: what a user can see printed, plus click's help texts."""
    tree = ast.parse(path.read_text(), str(path))
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                docstrings.add(id(body[0].value))
    return [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)
            and isinstance(n.value, str) and id(n) not in docstrings]


def test_messages_in_the_code_have_no_project_history():
    found = {}
    for folder in SOURCE_DIRS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            hits = [h for s in _message_strings(path) for h in _hits(s)]
            if hits:
                found[str(path.relative_to(ROOT))] = hits
    assert found == {}
