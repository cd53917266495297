"""Write a muscle file for any URDF, as far as its joints allow (for tests on shipped URDFs).

A description package ships a URDF and nothing else; to show that PIMBS loads it as shipped,
a muscle file is generated the way a user would write a first one: up to two movable
revolute joints are driven, each by an antagonist pair whose via points sit on either side
of the joint axis, one in the parent link's frame and one in the child link's. Every other
joint stays locked at its default. A URDF without a usable joint gets the reason, never a
silent skip.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import yaml

from pimbs_calibration.urdf_model import UrdfJoint, link_masses, parse_joints

MAX_JOINTS = 2
MOMENT_ARM = 0.02  # m: offset of both via points from the joint axis (the moment arm at 0)
SPAN = 0.04  # m: how far each via point sits from the joint origin along the muscle
HALF_RANGE = 0.25  # rad: sampling range around the joint's home angle, within the limits
DEFAULTS = {"K": 1000.0, "f_max": 600.0, "f_floor": 10.0, "counts_per_m": 108650.0,
            "loadcell_n_per_count": 0.25, "loadcell_offset_counts": 2048.0}


def usable_joints(urdf: Path) -> tuple[list[UrdfJoint], str]:
    """Up to ``MAX_JOINTS`` joints a muscle pair can drive, and why others were passed over."""
    text = urdf.read_text(errors="replace")
    masses = link_masses(text)
    picked: list[UrdfJoint] = []
    seen: dict[str, int] = {}
    for joint in parse_joints(urdf, text).values():
        why = _unusable(joint, masses)
        if why is None:
            picked.append(joint)
            if len(picked) == MAX_JOINTS:
                break
        else:
            seen[why] = seen.get(why, 0) + 1
    reason = "; ".join(f"{n} joint(s) {why}" for why, n in seen.items()) or "no joints"
    return picked, reason


def _unusable(joint: UrdfJoint, masses: dict[str, float]) -> str | None:
    if joint.type != "revolute":
        return f"{joint.type}, not revolute"
    if joint.mimic is not None:
        return "mimic"
    if not (math.isfinite(joint.lower) and math.isfinite(joint.upper)
            and joint.lower < joint.upper):
        return "without finite increasing limits"
    if masses.get(joint.child, 0.0) <= 0.0:
        return "whose child link has no mass"
    return None


def write_muscle_file(urdf: Path, out_dir: Path) -> Path | str:
    """The generated ``.muscles.yaml`` in ``out_dir``, or why this URDF has none."""
    joints, reason = usable_joints(urdf)
    if not joints:
        return f"no usable joint ({reason})"
    frames = _joint_frames(urdf)
    muscles = []
    for joint in joints:
        rotation, origin, axis = frames[joint.name]
        u, v = _perpendiculars(axis)
        # the pair is symmetric about the axis at the middle of the range, not at 0 (which
        # may lie outside the limits): the child's point is placed turned back by that angle
        back = _about(axis, -float(np.mean(_range(joint))))
        for side, sign in (("flexor", 1.0), ("extensor", -1.0)):
            near = sign * MOMENT_ARM * u
            muscles.append({
                "name": f"{joint.name}_{side}", "board_id": len(muscles) + 1,
                "path": [{"link": joint.parent,
                          "point": _listed(origin + rotation @ (near - SPAN * v))},
                         {"link": joint.child, "point": _listed(back @ (near + SPAN * v))}]})
    description = {
        "robot": f"generated-{urdf.stem}", "urdf": str(urdf.resolve()),
        "joint_encoders": True,
        "joints": [{"name": j.name, "range": _range(j)} for j in joints],
        "defaults": DEFAULTS, "muscles": muscles}
    path = out_dir / f"{urdf.stem}.muscles.yaml"
    path.write_text(yaml.safe_dump(description, sort_keys=False))
    return path


def _range(joint: UrdfJoint) -> list[float]:
    home = min(max(0.0, joint.lower), joint.upper)
    return [max(joint.lower, home - HALF_RANGE), min(joint.upper, home + HALF_RANGE)]


def _listed(point: np.ndarray) -> list[float]:
    return [round(float(x), 9) for x in point]


def _perpendiculars(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit u ⊥ axis and v = axis × u: a muscle along v at offset u has moment arm |u|."""
    a = axis / np.linalg.norm(axis)
    helper = np.eye(3)[int(np.argmin(np.abs(a)))]
    u = np.cross(a, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(a, u)


def _about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation by ``angle`` about ``axis`` (Rodrigues)."""
    a = axis / np.linalg.norm(axis)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k


def _joint_frames(urdf: Path) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per joint: rotation and position of its frame in the parent link, and its axis."""
    frames = {}
    for el in ET.fromstring(urdf.read_text(errors="replace")).findall("joint"):
        origin = el.find("origin")
        xyz = _floats(origin.get("xyz") if origin is not None else None)
        rpy = _floats(origin.get("rpy") if origin is not None else None)
        axis_el = el.find("axis")
        axis = (_floats(axis_el.get("xyz")) if axis_el is not None
                else np.array([1.0, 0.0, 0.0]))  # the URDF default
        frames[el.get("name", "")] = (_rpy(*rpy), xyz, axis)
    return frames


def _floats(text: str | None) -> np.ndarray:
    return np.array([float(x) for x in (text or "0 0 0").split()])


def _rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF's fixed-axis roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch),
                              math.sin(pitch), math.cos(yaw), math.sin(yaw))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])
