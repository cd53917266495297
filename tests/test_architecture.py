"""The house's rules, checked on the source: each room imports only the rooms below it, and
no module imports itself back through others (no circles), so data flows one way.

Imports under ``if TYPE_CHECKING:`` are annotations only and never run; every other import,
at module level or inside a function, is an edge.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# folder -> the name it installs (and is imported) under
ROOMS = {"calibration": "pimbs_calibration", "pimbs_recording": "pimbs_recording",
         "pimbs_arm": "pimbs_arm", "pimbs_sim": "pimbs_sim", "pimbs_hw": "pimbs_hw",
         "pimbs_import": "pimbs_import", "pimbs_learn": "pimbs_learn", "cli": "pimbs_cli"}
# what each room may import (besides itself); the table of docs/design.md
ALLOWED = {
    "pimbs_calibration": set(),
    "pimbs_recording": set(),
    "pimbs_arm": {"pimbs_calibration"},
    "pimbs_sim": {"pimbs_calibration", "pimbs_arm", "pimbs_recording"},
    "pimbs_hw": {"pimbs_calibration", "pimbs_arm", "pimbs_recording", "pimbs_sim"},
    "pimbs_import": {"pimbs_calibration", "pimbs_arm", "pimbs_recording", "pimbs_sim"},
    "pimbs_learn": {"pimbs_calibration", "pimbs_arm", "pimbs_recording", "pimbs_sim"},
    "pimbs_cli": set(ROOMS.values()),
}


def _modules() -> dict[str, Path]:
    out = {}
    for folder, name in ROOMS.items():
        for p in (ROOT / folder).rglob("*.py"):
            rel = p.relative_to(ROOT / folder).with_suffix("")
            parts = [name, *rel.parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = p
    return out


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _imports(path: Path, module: str) -> set[str]:
    """Runtime imports of one file, as dotted module names (relative ones resolved)."""
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for sub in child.orelse:
                    visit(sub)
                continue
            if isinstance(child, ast.Import):
                found.update(a.name for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:  # relative: from the package this file is in (or is)
                    parts = module.split(".")
                    keep = len(parts) - child.level + (path.name == "__init__.py")
                    base = ".".join([*parts[:keep], base] if base else parts[:keep])
                found.add(base)
                found.update(f"{base}.{a.name}" for a in child.names)
            visit(child)

    visit(ast.parse(path.read_text(), filename=str(path)))
    return found


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    return {m: {i for i in _imports(p, m) if i in mods and i != m} for m, p in mods.items()}


def test_each_room_imports_only_the_rooms_below_it():
    wrong = []
    for mod, deps in _graph().items():
        room = mod.split(".")[0]
        for d in deps:
            other = d.split(".")[0]
            if other != room and other not in ALLOWED[room]:
                wrong.append(f"{mod} imports {d}")
    assert not wrong, "imports running back up:\n" + "\n".join(sorted(wrong))


def test_learning_and_diagnosis_never_import_the_bus():
    hw = [f"{m} imports {d}" for m, deps in _graph().items() if m.startswith("pimbs_learn")
          for d in deps if d.startswith("pimbs_hw")]
    assert not hw


def test_no_module_imports_itself_back():
    graph = _graph()
    # a package's __init__ importing its own modules is not a cycle of rooms: drop pkg -> child
    graph = {m: {d for d in deps if not d.startswith(m + ".")} for m, deps in graph.items()}
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def dfs(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                dfs(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            dfs(m)
    assert not cycles, "import circles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_every_room_installs_under_its_folder_name():
    import tomllib

    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    packages, dirs = set(cfg["packages"]), cfg.get("package-dir", {})
    for folder, name in ROOMS.items():
        assert name in packages, f"{name} ({folder}/) is not installed"
        if folder != name:  # the design's two folders with documented install names
            assert dirs.get(name) == folder
    for sub in ROOT.glob("pimbs_*/**/__init__.py"):
        pkg = ".".join(sub.parent.relative_to(ROOT).parts)
        assert pkg in packages, f"{pkg} is a package folder that pyproject.toml does not install"
