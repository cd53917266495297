"""Every command block of the README runs as written, from the repository's root.

Each ```bash block is listed here, by its first line, with how the test treats it: run (in a
fresh copy of the root's layout, with this test's environment as `.venv`), or not run and
why (set-up that installs, the test command itself). A run may rewrite only the parameters
declared here, each with its reason (a smaller --samples, a simulated port where the README
names a CAN adapter); everything else is the text the reader types. What the README quotes
from a block's output is checked in that output, and every file a walkthrough writes must be
one git ignores, so following the README leaves the checkout clean.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
ACME = "fixtures/foreign_arm/acme_left_arm.muscles.yaml"
LAB = "fixtures/lab-board/two-link-lab.muscles.yaml"


@dataclass(frozen=True)
class Block:
    starts: str  # the block's first line as the README has it
    run: bool
    why: str  # why it is not run, or what its rewrites stand for
    rewrite: tuple[tuple[str, str], ...] = ()  # (text in the block, what the test runs)
    # what the README says of the block's output, and what the output must then contain
    quotes: tuple[tuple[str, str], ...] = ()


BLOCKS = (
    Block("python3 -m venv .venv && .venv/bin/pip install torch==2.13.0", False,
          "set-up: installs torch from the network"),
    Block("python3 -m venv .venv && .venv/bin/pip install -q . && .venv/bin/pimbs collect",
          True, "the main job, in the environment its set-up part made (the one these tests "
          "run in), on a few samples and epochs",
          rewrite=(("python3 -m venv .venv && .venv/bin/pip install -q . && ", ""),
                   ("--samples 40", "--samples 4"), ("--n-train 30", "--n-train 3"),
                   ("--epochs 2000", "--epochs 3"))),
    Block('python3 -m venv .venv && .venv/bin/pip install -q ".[test]"', False,
          "set-up and the test command: this is what runs these tests (.ci/run)"),
    Block("source .venv/bin/activate", True, "as written"),
    Block(f"pimbs robot {ACME} --plot acme.png", True, "as written",
          quotes=(("`l_wrist_roll continuous at 0.5`", "l_wrist_roll continuous at 0.5"),
                  ("`l_gripper_mimic revolute at -0.3 (mimic of l_gripper)`",
                   "l_gripper_mimic revolute at -0.3 (mimic of l_gripper)"),
                  ("the total mass (11.48 kg, of which 3.48 kg moved by the driven joints)",
                   "total mass 11.48 kg (3.48 kg moved by the driven joints)"),
                  ("over 209 poses", "over 209 poses"),
                  ("e.g. `el_flexor` -29.0..-25.7 mm about the elbow",
                   "el_flexor - - -29.0..-25.7"))),
    Block(f"pimbs simulate --robot {ACME} --samples 200", True,
          "the collection on 32 of the 200 poses (diagnose needs 30 paired samples)",
          rewrite=(("--samples 200 --seed 1 \\\n", "--samples 32 --seed 1 \\\n"),),
          quotes=tuple((q, q) for q in ("14 of 200 drawn poses need tensions beyond 0.9*f_max "
                                   "(or the arm would not stay there) and were replaced by "
                                   "feasible draws from seed 1 (samples 50, 61, 66, ",))),
    Block("python -m pimbs_import.synthetic lab.bag --poses 60", True,
          "training for a few epochs", rewrite=(("--epochs 2000", "--epochs 3"),),
          quotes=(("The demo log (60 held poses) imports to 60 rows",
                   "wrote lab.parquet: 60 held poses"),)),
    Block(f"pimbs scan --port can0 --robot {LAB}", True,
          "no CAN adapter here: the same boards simulated (--port virtual); the test answers "
          "`zero`'s question (is the arm at its home pose?) with --yes; three samples",
          rewrite=(("--port can0", "--port virtual"),
                   ("# arm held at home", "--yes  # arm held at home"),
                   ("--samples 496", "--samples 3"))),
    Block("python benchmarks/readme_numbers.py          # reruns", False,
          "regenerates the README's measured numbers (benchmarks of minutes to hours)"),
)


def _bash_blocks(text: str) -> list[str]:
    """The body of every ```bash block (indented ones in lists too), dedented."""
    out = []
    for m in re.finditer(r"^( *)```bash\n(.*?)^\1```", text, re.S | re.M):
        indent = len(m[1])
        out.append("".join(line[indent:] for line in m[2].splitlines(keepends=True)))
    return out


def _spec(body: str) -> Block:
    found = [b for b in BLOCKS if body.startswith(b.starts)]
    assert len(found) == 1, f"README block not listed (or listed twice) here:\n{body}"
    return found[0]


def test_every_command_block_is_listed_with_how_it_is_tested():
    bodies = _bash_blocks(README)
    assert len(bodies) == len(BLOCKS)
    for body in bodies:
        spec = _spec(body)
        for old, _ in spec.rewrite:
            assert old in body, f"rewrite {old!r} no longer matches the README:\n{body}"
        flat = " ".join(README.split())
        for says, _ in spec.quotes:
            assert " ".join(says.split()) in flat, f"the README no longer says {says!r}"


def test_no_two_walkthroughs_write_the_same_file():
    """Followed one after the other from the root, no walkthrough trips over another's
    output (every command refuses to replace a file without --force)."""
    written: dict[str, str] = {}
    for body in _bash_blocks(README):
        spec = _spec(body)
        if not spec.run:
            continue
        for line in _commands(body):
            if "--force" in line or "--resume" in line:
                continue
            for out in re.findall(r"--(?:out|plot|json) (\S+)", line):
                assert out not in written, f"{out}: written by {written[out]!r} and {line!r}"
                written[out] = line


def _commands(body: str) -> list[str]:
    """The block's command lines, continuations joined."""
    return [line for line in body.replace("\\\n", " ").splitlines() if line.strip()]


def _root_copy(tmp: Path) -> Path:
    """A directory laid out as the repository's root: every tracked top-level folder linked,
    but the fixtures copied (`pimbs zero` writes beside a robot file), and `.venv` this
    test's environment."""
    root = tmp / "root"
    root.mkdir()
    for entry in ROOT.iterdir():
        if entry.name in ("fixtures", ".venv", ".git") or not entry.is_dir():
            continue
        (root / entry.name).symlink_to(entry)
    shutil.copytree(ROOT / "fixtures", root / "fixtures")
    (root / ".venv").symlink_to(Path(sys.prefix))
    return root


def _ignored_by_git(paths: list[str]) -> list[str]:
    """The paths (relative to the root) the repository's .gitignore ignores."""
    if not paths:
        return []
    run = subprocess.run(["git", "check-ignore", "--no-index", "--stdin"], cwd=ROOT,
                         input="\n".join(paths) + "\n", capture_output=True, text=True)
    return run.stdout.split()


@pytest.mark.parametrize("body", [b for b in _bash_blocks(README) if _spec(b).run],
                         ids=lambda body: _spec(body).starts[:40])
def test_walkthrough_runs_from_the_root_as_written(body, tmp_path):
    spec = _spec(body)
    script = body
    for old, new in spec.rewrite:
        script = script.replace(old, new)
    root = _root_copy(tmp_path)
    before = {p for p in root.rglob("*")}
    env = {**os.environ, "PATH": f"{Path(sys.prefix) / 'bin'}{os.pathsep}{os.environ['PATH']}",
           "OMP_NUM_THREADS": "1", "COLUMNS": "100"}
    env.pop("PYTHONPATH", None)
    run = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", script], cwd=root, env=env,
                         capture_output=True, text=True, timeout=900)
    output = run.stdout + run.stderr
    assert run.returncode == 0, f"{script}\n---\n{output[-4000:]}"
    assert "Traceback" not in output, output[-4000:]
    # our numerics' warnings never reach the reader's screen
    assert not re.findall(r"\b\w+Warning\b", output), output[-4000:]
    flat = " ".join(output.split())  # columns aligned with spaces compare as one space
    for says, shown in spec.quotes:
        assert shown in flat, f"the README says {says!r}; the output is:\n{output}"
    made = sorted(str(p.relative_to(root)) for p in set(root.rglob("*")) - before
                  if p.is_file())
    if shutil.which("git") is None or subprocess.run(
            ["git", "rev-parse", "--git-dir"], cwd=ROOT, capture_output=True).returncode:
        pytest.skip("not a git checkout: cannot check the outputs are ignored")
    ignored = set(_ignored_by_git(made))
    assert [m for m in made if m not in ignored] == [], "outputs git would show as new files"
