"""Regenerate the README's measured numbers from the benchmark scripts that produce them.

Every number the README quotes from a measurement sits in a marked block

    <!-- numbers:NAME -->
    ...
    <!-- /numbers -->

where NAME is a script ``benchmarks/NAME.py``. A script that can write its block itself
says so with ``README_BLOCK = True`` and prints the block's Markdown when run with
``--readme``; this tool runs it and replaces the block's text. The other blocks (long
benchmarks: minutes to hours of CPU) keep the text measured with the command they name, and
are rerun by hand with that command.

    .venv/bin/python benchmarks/readme_numbers.py            # regenerate every README_BLOCK script
    .venv/bin/python benchmarks/readme_numbers.py test_count # just these
    .venv/bin/python benchmarks/readme_numbers.py --check    # list the blocks, change nothing
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
# markers stand on lines of their own, so prose may mention them
BLOCK = re.compile(r"^<!-- numbers:(?P<name>[A-Za-z0-9_]+) -->\n(?P<body>.*?)^<!-- /numbers -->$",
                   re.S | re.M)


@dataclass(frozen=True)
class Block:
    name: str
    body: str
    start: int  # offsets of the body in the README text
    end: int

    @property
    def script(self) -> Path:
        return ROOT / "benchmarks" / f"{self.name}.py"

    def regenerates(self) -> bool:
        """Whether the script writes this block itself (``README_BLOCK = True``)."""
        return self.script.is_file() and re.search(
            r"^README_BLOCK = True", self.script.read_text(), re.M) is not None


def blocks(text: str) -> list[Block]:
    """The marked blocks of ``text``, in order."""
    return [Block(m["name"], m["body"], m.start("body"), m.end("body"))
            for m in BLOCK.finditer(text)]


def unmarked(text: str) -> str:
    """``text`` with every marked block's body removed (what no script produced)."""
    return BLOCK.sub("", text)


def regenerate(text: str, names: set[str] | None, python: str = sys.executable) -> str:
    """``text`` with the blocks of ``names`` (default: every block whose script writes it)
    replaced by their scripts' ``--readme`` output."""
    out, pos = [], 0
    for block in blocks(text):
        if names is not None and block.name not in names:
            continue
        if not block.regenerates():
            if names is not None:
                raise SystemExit(f"{block.script.relative_to(ROOT)} does not write its README "
                                 "block (no README_BLOCK = True); rerun it with the command the "
                                 "block names and edit the block by hand")
            continue
        run = subprocess.run([python, str(block.script), "--readme"], cwd=ROOT,
                             capture_output=True, text=True, check=False)
        if run.returncode != 0:
            raise SystemExit(f"{block.script.relative_to(ROOT)} --readme failed "
                             f"(exit {run.returncode}): {run.stderr.strip()[-400:]}")
        body = run.stdout.rstrip("\n") + "\n"
        out += [text[pos:block.start], body]
        pos = block.end
    return "".join(out) + text[pos:]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", help="blocks to regenerate (default: every block whose "
                    "script writes it)")
    ap.add_argument("--check", action="store_true", help="list the blocks, change nothing")
    args = ap.parse_args()
    text = README.read_text()
    found = blocks(text)
    missing = [b.name for b in found if not b.script.is_file()]
    if missing:
        print(f"README.md: marked blocks name no script in benchmarks/: {', '.join(missing)}",
              file=sys.stderr)
        return 1
    if args.check:
        for b in found:
            how = "regenerated" if b.regenerates() else "by hand, with its command"
            print(f"{b.name:22s} benchmarks/{b.name}.py  ({how})")
        return 0
    unknown = set(args.names) - {b.name for b in found}
    if unknown:
        print(f"README.md has no block named {', '.join(sorted(unknown))}", file=sys.stderr)
        return 1
    new = regenerate(text, set(args.names) or None)
    if new != text:
        README.write_text(new)
    print(f"README.md: {len(found)} marked blocks; "
          f"{'changed' if new != text else 'unchanged'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
