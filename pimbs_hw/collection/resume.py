"""Opening the output recording: a fresh file, or ``--resume`` of an interrupted one.

Resuming is only honest when the file was made by the same sequence: same robot, seed, sample
count and map. Anything else would splice two different collections into one file that looks
valid, so it is refused with a message that says which key differs and what to do.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pimbs_arm.model import ArmModel
from pimbs_hw.collection.temperature import temperature_note
from pimbs_recording.format import RecordingWriter, make_meta, read_recording

# metadata keys that must match for --resume (they define the pose/tension sequence)
RESUME_KEYS = ("robot", "joints", "muscles", "seed", "samples", "map", "schema", "poses_file")
_OPTION = {"robot": "--robot", "seed": "--seed", "samples": "--samples", "map": "--map",
           "schema": "--schema", "poses_file": "--poses-file"}


def collection_meta(model: ArmModel, plan_meta: Mapping[str, Any], *, port: str,
                    simulated: bool, settle: Mapping[str, Any],
                    move: Mapping[str, Any]) -> dict[str, Any]:
    """The recording's ``pimbs`` metadata: identity of the sequence plus how it was taken."""
    return make_meta(model.joints, model.muscles, "simulation" if simulated else "hardware",
                     robot=model.robot.name, **plan_meta, port=port,
                     generator="pimbs collect",
                     theta_source="joint_encoders" if model.robot.joint_encoders else "model",
                     settle=dict(settle), move=dict(move), joint_range=model.joint_range.tolist(),
                     K=model.K.tolist(), temperature=temperature_note(model.robot))


class ResumeError(ValueError):
    """The file to resume was made by a different collection."""


def open_recording(path: Path, meta: Mapping[str, Any], resume: bool
                   ) -> tuple[RecordingWriter, int]:
    """Writer for ``path`` and the first sample index still to collect.

    Raises ``ResumeError`` for a mismatching file, ``RecordingError`` for an invalid one or
    for an existing file without ``resume``.
    """
    if resume and path.exists():
        existing = read_recording(path).meta
        if existing.get("generator") != "pimbs collect":
            made_by = existing.get("generator") or "another tool"
            raise ResumeError(f"cannot resume {path}: it was written by {made_by}, not by "
                              "pimbs collect, so there is no collection to continue; choose "
                              "another --out for a new collection")
        for key in RESUME_KEYS:
            old, new = existing.get(key), meta.get(key)
            if old == new:
                continue
            fix = (f"rerun with {_OPTION[key]} {old}" if key in _OPTION and old is not None
                   else f"rerun without {_OPTION[key]}" if key in _OPTION
                   else "the robot description changed since; use the one it was made with")
            raise ResumeError(f"cannot resume {path}: it was collected with {key}={old!r}, "
                              f"this run has {key}={new!r}; {fix} to continue it, or choose "
                              f"another --out for a new collection")
    writer = RecordingWriter(path, meta, resume=resume)
    rec = writer.recording
    start = 0 if rec is None or rec.n_rows == 0 else int(rec.sample[-1]) + 1
    return writer, start
