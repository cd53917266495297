"""Load and validate a robot description: a URDF (skeleton) plus a ``.muscles.yaml`` (muscles).

The URDF carries what pinocchio needs (links, revolute joints, limits, masses, inertias); the
muscle file carries what the URDF cannot say: which joints are actuated and in what column
order, where each muscle's via points sit, its elastic element, its board and the board's
sensor calibration. Every mistake is reported as a ``DescriptionError`` naming the file and the
field, because a wrong description silently corrupts every recording made with it.

Muscle file layout (values under ``defaults`` apply to every muscle that does not set them)::

    robot: two-link-4-muscle
    urdf: two-link-4-muscle.urdf          # relative to this file
    joint_encoders: true
    joints:                               # actuated joints, in column order
      - {name: shoulder_pitch, range: [-0.5, 0.5]}
    defaults: {K: 1000, f_max: 600, f_floor: 10, counts_per_m: ..., ...}
                                          # optional protocol: pimbs-v1 (default),
                                          # odrive-cansimple, or lab.profile.yaml
    muscles:
      - name: m0
        board_id: 1
        path:                             # >= 2 via points, fixed on links
          - {link: base_link, point: [0.0, 0.0, 0.05]}
          - {link: upper_arm, point: [0.0, 0.0, -0.1]}
"""

from __future__ import annotations

import importlib.resources
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

MUSCLE_SUFFIX = ".muscles.yaml"
_BUILTIN = ("two-link-4-muscle", "left-arm-5dof")
_MUSCLE_FLOATS = (
    "K", "f_max", "f_floor", "counts_per_m", "loadcell_n_per_count", "loadcell_offset_counts",
)
# Fields that must be strictly positive (a zero or negative value is physically meaningless).
_POSITIVE = ("K", "f_max", "counts_per_m", "loadcell_n_per_count")


class DescriptionError(ValueError):
    """A robot description is broken; the message names the file, the field and the fix."""

    def __init__(self, path: Path | str, field: str, problem: str, fix: str) -> None:
        self.path = Path(path)
        self.field = field
        super().__init__(f"{self.path}: field '{field}': {problem}. {fix}")


class _ArrayFieldsEq:
    """Value equality for frozen dataclasses holding numpy arrays (which dataclass ``==``
    cannot compare); the arrays are made read-only so the instances really are frozen."""

    def __post_init__(self) -> None:
        for value in self.__dict__.values():
            if isinstance(value, np.ndarray):
                value.flags.writeable = False

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return all(np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b
                   for a, b in zip(self.__dict__.values(), other.__dict__.values(), strict=True))

    def __hash__(self) -> int:
        return hash(tuple(v.tobytes() if isinstance(v, np.ndarray) else v
                          for v in self.__dict__.values()))


@dataclass(frozen=True, eq=False)
class ViaPoint(_ArrayFieldsEq):
    """A point the muscle wire passes through, fixed in the frame of ``link`` (metres)."""

    link: str
    point: np.ndarray  # (3,)


@dataclass(frozen=True)
class MuscleSpec:
    """One muscle: its wire path, elastic element, limits and board calibration."""

    name: str
    board_id: int
    path: tuple[ViaPoint, ...]
    K: float  # elastic coefficient of f = exp(K dn) - 1, 1/m
    f_max: float  # tension ceiling, N
    f_floor: float  # holding floor (slack removal), N
    counts_per_m: float  # motor encoder counts per metre of wire
    loadcell_n_per_count: float
    loadcell_offset_counts: float
    # board protocol: None = PIMBS v1; a shipped profile name (odrive-cansimple) or the
    # absolute path of a lab's ``*.profile.yaml`` (a .dbc + mapping; see pimbs_hw)
    protocol: str | None = None


@dataclass(frozen=True, eq=False)
class RobotDescription(_ArrayFieldsEq):
    """A validated robot: skeleton file, actuated joints and muscles."""

    name: str
    urdf_path: Path
    muscle_path: Path
    joints: tuple[str, ...]  # actuated joint names, in column order
    joint_range: np.ndarray  # (N, 2) sampling range, inside the URDF limits
    joint_encoders: bool
    muscles: tuple[MuscleSpec, ...]


def builtin_robots() -> list[str]:
    """Names of the robots shipped in ``calibration/robots``."""
    return list(_BUILTIN)


def load_robot(name_or_path: str | Path) -> RobotDescription:
    """Load a built-in robot by name, or a description from a path to its ``.muscles.yaml``.

    Built-ins are read through ``importlib.resources`` so an installed (non-editable) package
    finds them. Raises ``DescriptionError`` for any broken or unknown description.
    """
    text = str(name_or_path)
    if text in _BUILTIN and not Path(text).exists():
        package = importlib.resources.files("pimbs_calibration")
        resource = package / "robots" / f"{text}{MUSCLE_SUFFIX}"
        with importlib.resources.as_file(resource) as path:
            return _load_file(Path(path))
    path = Path(text)
    if not path.is_file():
        raise DescriptionError(
            path, "robot", "no such built-in robot or muscle file",
            f"Use one of {', '.join(_BUILTIN)} or a path to a *{MUSCLE_SUFFIX} file",
        )
    return _load_file(path)


def _load_file(path: Path) -> RobotDescription:
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise DescriptionError(path, "<file>", f"cannot read YAML ({exc})",
                               "Fix the YAML syntax") from exc
    if not isinstance(raw, dict):
        raise DescriptionError(path, "<file>", "top level is not a mapping",
                               "Write robot, urdf, joints, joint_encoders and muscles keys")
    name = _require(raw, "robot", str, path, "robot")
    urdf_path = path.parent / _require(raw, "urdf", str, path, "urdf")
    urdf = _read_urdf(urdf_path, path)
    joints, joint_range = _parse_joints(raw, urdf, path)
    encoders = _require(raw, "joint_encoders", bool, path, "joint_encoders")
    muscles = _parse_muscles(raw, urdf, joints, path)
    return RobotDescription(
        name=name, urdf_path=urdf_path.resolve(), muscle_path=path.resolve(), joints=joints,
        joint_range=joint_range, joint_encoders=encoders, muscles=muscles,
    )


def _require(raw: dict, key: str, kind: type | tuple[type, ...], path: Path, field: str) -> Any:
    """Fetch ``raw[key]`` checking its type; bool is not accepted where a number is expected."""
    if key not in raw:
        raise DescriptionError(path, field, "missing", f"Add '{key}' to {path.name}")
    value = raw[key]
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if (bool not in kinds and isinstance(value, bool)) or not isinstance(value, kinds):
        names = " or ".join(k.__name__ for k in kinds)
        raise DescriptionError(path, field, f"expected {names}, got {value!r}",
                               f"Write a {names} for '{key}'")
    return value


def _read_urdf(urdf_path: Path, path: Path):
    """Build the pinocchio model; the URDF is where limits and links are checked against."""
    import pinocchio as pin  # lazy: only needed once a description is actually loaded

    if not urdf_path.is_file():
        raise DescriptionError(path, "urdf", f"URDF file {urdf_path} not found",
                               "Give the URDF path relative to the muscle file")
    try:
        return pin.buildModelFromUrdf(str(urdf_path))
    except Exception as exc:  # pinocchio raises plain RuntimeError/ValueError on parse errors
        raise DescriptionError(path, "urdf", f"cannot parse URDF {urdf_path} ({exc})",
                               "Fix the URDF so pinocchio can load it") from exc


def _parse_joints(raw: dict, model, path: Path) -> tuple[tuple[str, ...], np.ndarray]:
    entries = _require(raw, "joints", list, path, "joints")
    movable = [n for n in list(model.names)[1:]]
    names: list[str] = []
    ranges = []
    for i, entry in enumerate(entries):
        field = f"joints[{i}]"
        if not isinstance(entry, dict):
            raise DescriptionError(path, field, "expected a mapping {name, range}",
                                   "Write '- {name: <joint>, range: [lo, hi]}'")
        name = _require(entry, "name", str, path, f"{field}.name")
        if name not in movable:
            raise DescriptionError(path, f"{field}.name", f"joint '{name}' is not a movable "
                                   f"joint of the URDF (has {movable})",
                                   "Use a revolute joint name from the URDF")
        if name in names:
            raise DescriptionError(path, f"{field}.name", f"joint '{name}' listed twice",
                                   "List each actuated joint once")
        jid = model.getJointId(name)
        if model.joints[jid].nq != 1 or model.joints[jid].nv != 1:
            raise DescriptionError(path, f"{field}.name", f"joint '{name}' is not revolute",
                                   "Only revolute joints are supported")
        rng = _vector(entry.get("range"), 2, path, f"{field}.range")
        q = model.joints[jid].idx_q
        lo, hi = model.lowerPositionLimit[q], model.upperPositionLimit[q]
        if not rng[0] < rng[1] or rng[0] < lo or rng[1] > hi:
            raise DescriptionError(path, f"{field}.range", f"{list(rng)} is not an increasing "
                                   f"range inside the URDF limits [{lo:g}, {hi:g}]",
                                   "Narrow the sampling range or widen the URDF limit")
        names.append(name)
        ranges.append(rng)
    missing = sorted(set(movable) - set(names))
    if missing:
        raise DescriptionError(path, "joints", f"URDF joints {missing} are not listed",
                               "List every movable URDF joint (or make it fixed in the URDF)")
    return tuple(names), np.array(ranges, dtype=np.float64).reshape(len(names), 2)


def _vector(value: Any, n: int, path: Path, field: str) -> np.ndarray:
    ok = isinstance(value, list) and len(value) == n and all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
        for v in value)
    if not ok:
        raise DescriptionError(path, field, f"expected {n} finite numbers, got {value!r}",
                               f"Write a list of {n} numbers")
    return np.array(value, dtype=np.float64)


def _parse_muscles(raw: dict, model, joints: tuple[str, ...], path: Path
                   ) -> tuple[MuscleSpec, ...]:
    entries = _require(raw, "muscles", list, path, "muscles")
    if not entries:
        raise DescriptionError(path, "muscles", "no muscles", "Describe at least one muscle")
    defaults = raw.get("defaults", {})
    if not isinstance(defaults, dict):
        raise DescriptionError(path, "defaults", "expected a mapping",
                               "Write 'defaults: {K: 1000, ...}' or remove it")
    muscles: list[MuscleSpec] = []
    for i, entry in enumerate(entries):
        if not isinstance(entry, dict):
            raise DescriptionError(path, f"muscles[{i}]", "expected a mapping",
                                   "Write each muscle as a mapping with name, board_id, path")
        muscles.append(_parse_muscle({**defaults, **entry}, i, model, joints, path))
    for key in ("name", "board_id"):
        seen: dict[Any, int] = {}
        for i, m in enumerate(muscles):
            value = getattr(m, key)
            if value in seen:
                raise DescriptionError(path, f"muscles[{i}].{key}",
                                       f"{value!r} is also used by muscles[{seen[value]}]",
                                       f"Give each muscle a unique {key}")
            seen[value] = i
    return tuple(muscles)


def _parse_muscle(entry: dict, i: int, model, joints: tuple[str, ...], path: Path
                  ) -> MuscleSpec:
    field = f"muscles[{i}]"
    name = _require(entry, "name", str, path, f"{field}.name")
    board_id = _require(entry, "board_id", int, path, f"{field}.board_id")
    values: dict[str, float] = {}
    for key in _MUSCLE_FLOATS:
        value = float(_require(entry, key, (int, float), path, f"{field}.{key}"))
        if not math.isfinite(value) or (key in _POSITIVE and value <= 0):
            raise DescriptionError(path, f"{field}.{key}", f"{value!r} is not a positive finite "
                                   "number" if key in _POSITIVE else "not finite",
                                   f"Set {key} to a physically meaningful value")
        values[key] = value
    if not 0 <= values["f_floor"] < values["f_max"]:
        raise DescriptionError(path, f"{field}.f_floor", f"{values['f_floor']} is not in "
                               f"[0, f_max={values['f_max']})", "Lower f_floor or raise f_max")
    via = _parse_path(_require(entry, "path", list, path, f"{field}.path"), model, joints,
                      path, f"{field}.path")
    protocol = entry.get("protocol")
    if protocol is not None:
        if not isinstance(protocol, str) or not protocol:
            raise DescriptionError(path, f"{field}.protocol", f"{protocol!r} is not a profile",
                                   "Write pimbs-v1, odrive-cansimple or a path to a "
                                   "*.profile.yaml")
        if protocol.endswith(".yaml"):
            protocol = str((path.parent / protocol).resolve())
            if not Path(protocol).is_file():
                raise DescriptionError(path, f"{field}.protocol", f"no file {protocol}",
                                       "Give the profile's path relative to this file")
    return MuscleSpec(name=name, board_id=board_id, path=via, protocol=protocol, **values)


def _parse_path(entries: list, model, joints: tuple[str, ...], path: Path, field: str
                ) -> tuple[ViaPoint, ...]:
    if len(entries) < 2:
        raise DescriptionError(path, field, f"{len(entries)} via point(s)",
                               "Give at least 2 via points (origin and insertion)")
    points = []
    for k, entry in enumerate(entries):
        sub = f"{field}[{k}]"
        if not isinstance(entry, dict):
            raise DescriptionError(path, sub, "expected a mapping {link, point}",
                                   "Write '- {link: <link>, point: [x, y, z]}'")
        link = _require(entry, "link", str, path, f"{sub}.link")
        if not model.existBodyName(link):
            links = [f.name for f in model.frames if f.type.name == "BODY"]
            raise DescriptionError(path, f"{sub}.link", f"link '{link}' is not in the URDF "
                                   f"(links: {links})", "Use a link name from the URDF")
        points.append(ViaPoint(link=link, point=_vector(entry.get("point"), 3, path,
                                                         f"{sub}.point")))
    # A muscle moves only if some actuated joint lies between two of its links.
    crossed = set()
    supports = [_supporting_joints(model, p.link) for p in points]
    for a, b in zip(supports, supports[1:], strict=False):
        crossed |= a ^ b
    if not crossed & set(joints):
        raise DescriptionError(path, field, "the path crosses no actuated joint (all via points "
                               "move together)", "Attach the via points to links on both sides "
                               "of at least one joint")
    return tuple(points)


def _supporting_joints(model, link: str) -> set[str]:
    """Names of the joints between the root and ``link``."""
    joint = model.frames[model.getBodyId(link)].parentJoint
    return {model.names[j] for j in model.supports[joint] if j != 0}
