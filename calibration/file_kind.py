"""Recognise a robot model file handed over where a muscle file belongs.

A new user's first try is ``pimbs robot arm.urdf``: the URDF is the file they have. Read as
YAML it fails with a syntax error about a colon on some line, which says nothing about the
real mistake. The first element of an XML file says what it is, so the refusal can say it.
"""

from __future__ import annotations

import re
from pathlib import Path

# the XML declaration, comments, doctype and processing instructions before the root element
_PROLOGUE = re.compile(r"\A(?:\ufeff)?(?:\s+|<\?.*?\?>|<!--.*?-->|<!DOCTYPE[^>]*>)*", re.S)
_ROOT = re.compile(r"<([A-Za-z_][\w.:-]*)")
MJCF_KIND = "a MuJoCo model (MJCF)"  # a robot description by itself (its tendons, muscles)
_KINDS = {"robot": "a URDF", "mujoco": MJCF_KIND, "sdf": "an SDF model"}
_SUFFIXES = {".urdf": "a URDF", ".xacro": "a xacro file", ".mjcf": MJCF_KIND,
             ".sdf": "an SDF model"}
HOW = ("write a .muscles.yaml that names it (urdf: FILE), lists the joints the muscles "
       "drive and each muscle's via points, and pass that instead (README: 'Your robot')")


def model_file_kind(path: Path, head: str | None = None) -> str | None:
    """``"a URDF"``, ``"a MuJoCo model (MJCF)"``, ... when ``path`` is a robot model file
    rather than a muscle file; None when it may be a muscle file.

    ``head``: the file's first characters, if already read (else up to 4 kB are read).
    """
    if head is None:
        try:
            with path.open("r", encoding="utf-8", errors="replace") as f:
                head = f.read(4096)
        except OSError:
            return None
    text = _PROLOGUE.sub("", head, count=1)
    if text.startswith("<"):
        root = _ROOT.match(text)
        tag = root.group(1).split(":")[-1] if root else ""
        if path.suffix == ".xacro" or ".xacro" in path.suffixes:
            return "a xacro file"
        return _KINDS.get(tag, f"an XML file (<{tag}>)" if tag else "an XML file")
    return _SUFFIXES.get(path.suffix.lower())


def not_a_muscle_file(path: Path, kind: str) -> str:
    """The one line that says what the file is and what is expected instead."""
    return f"{path} is {kind}, not a muscle file: {HOW.replace('FILE', path.name)}"
