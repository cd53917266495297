"""Load and validate a robot description: a URDF (skeleton) plus a ``.muscles.yaml`` (muscles).

The URDF carries what pinocchio needs (links, joints, limits, masses, inertias) and is used as
shipped (``urdf_model``: meshes ignored, continuous and mimic joints understood, joints the
muscles do not drive locked); the muscle file carries what the URDF cannot say: which joints
are actuated and in what column order, where each muscle's via points sit, its elastic
element, its board and the board's sensor calibration. Every mistake is reported as a
``DescriptionError`` naming the file and the field, because a wrong description silently
corrupts every recording made with it.

Muscle file layout (values under ``defaults`` apply to every muscle that does not set them)::

    robot: two-link-4-muscle
    urdf: two-link-4-muscle.urdf          # relative to this file, or package://pkg/path
    package_path: [../src]                # optional: where package:// looks (+ ROS_PACKAGE_PATH)
    joint_encoders: true
    joints:                               # actuated joints, in column order
      - {name: shoulder_pitch, range: [-0.5, 0.5]}
    lock: {wrist_roll: 0.3}               # optional: value of a joint not driven (default 0)
    defaults: {K: 1000, f_max: 600, f_floor: 10, counts_per_m: ..., ...}
                                          # optional protocol: pimbs-v1 (default),
                                          # odrive-cansimple, or lab.profile.yaml
    muscles:
      - name: m0
        board_id: 1
        direction: 1                      # optional: -1 if the wire is wound the other way
        path:                             # >= 2 via points, fixed on links
          - {link: base_link, point: [0.0, 0.0, 0.05]}
          - {link: upper_arm, point: [0.0, 0.0, -0.1]}

An MJCF (MuJoCo's XML) is a description too, bare (``arm.xml``) or named by a muscle file
(``mjcf: arm.xml`` instead of ``urdf:``, mapping spatial tendons to boards by name): see
``load_mjcf_description`` and docs/mujoco.md.
"""

from __future__ import annotations

import importlib.resources
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pimbs_calibration.coupling import (
    CouplingError,
    JointCoupling,
    coupling_order,
    moved_by,
    root_leader,
)
from pimbs_calibration.file_kind import MJCF_KIND, model_file_kind, not_a_muscle_file
from pimbs_calibration.urdf_model import (
    UNLIMITED,
    ReducedModel,
    UrdfError,
    UrdfJoint,
    parse_joints,
    reduce,
    refuse_xacro,
    resolve_package_url,
    ros_package_path,
)

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


class NotAMuscleFileError(DescriptionError):
    """A URDF, MJCF or other model file given where the muscle file belongs."""

    def __init__(self, path: Path | str, kind: str) -> None:
        self.path, self.field, self.kind = Path(path), "<file>", kind
        ValueError.__init__(self, not_a_muscle_file(self.path, kind))


class RobotNotFoundError(DescriptionError):
    """A robot named by the caller (a command's ``--robot``) that is no built-in robot and
    no file: nothing inside a description is wrong, so no field is named."""

    def __init__(self, path: Path | str) -> None:
        self.path, self.field = Path(path), "<file>"
        where = ("" if self.path.is_absolute() else
                 f" (a relative path starts from the current directory, {Path.cwd()})")
        ValueError.__init__(
            self, f"{self.path}: no such built-in robot or muscle file{where}. Use one of "
            f"{', '.join(_BUILTIN)}, a path to a *{MUSCLE_SUFFIX} file or an MJCF *.xml")


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
    # winding direction (docs/boards.md): +1 when a positive motor turn reels the wire in
    # (tension rises, length shortens), -1 when the wire is wound the other way round
    direction: int = 1


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
    locked: tuple[tuple[str, float], ...] = ()  # joints not driven, and the value they hold
    followers: tuple[tuple[str, str, float, float], ...] = ()  # mimic, leader, multiplier, c
    # an MJCF's joint equalities that move a joint with a driven one, each after the one
    # that moves its leader (see pimbs_calibration.coupling)
    couplings: tuple[JointCoupling, ...] = ()
    # an MJCF whose spatial tendons are the muscles (then urdf_path is that file too and the
    # muscles' via-point paths are empty: MuJoCo routes them); None for URDF + via points
    mjcf_path: Path | None = None


def builtin_robots() -> list[str]:
    """Names of the robots shipped in ``calibration/robots``."""
    return list(_BUILTIN)


def load_robot(name_or_path: str | Path, package_path: Sequence[Path] = ()
               ) -> RobotDescription:
    """Load a built-in robot by name, or a description from a path to its ``.muscles.yaml``.

    Built-ins are read through ``importlib.resources`` so an installed (non-editable) package
    finds them. ``package_path``: directories searched first for a ``urdf: package://...``
    (then the muscle file's ``package_path``, then ``ROS_PACKAGE_PATH``). Raises
    ``DescriptionError`` for any broken or unknown description.
    """
    text = str(name_or_path)
    if text in _BUILTIN and not Path(text).exists():
        package = importlib.resources.files("pimbs_calibration")
        resource = package / "robots" / f"{text}{MUSCLE_SUFFIX}"
        with importlib.resources.as_file(resource) as path:
            return _load_file(Path(path))
    path = Path(text)
    if not path.is_file():
        raise RobotNotFoundError(path)
    if path.suffix.lower() == ".xml":
        from pimbs_calibration.mjcf import is_mjcf

        if not is_mjcf(path):
            raise DescriptionError(path, "<file>", "not an MJCF (its root element is not "
                                   "<mujoco>)", "Give an MJCF model, or a URDF through a "
                                   f"*{MUSCLE_SUFFIX} file that names it")
        return load_mjcf_description(path, {}, path)
    return _load_file(path, package_path)


def _load_file(path: Path, package_path: Sequence[Path] = ()) -> RobotDescription:
    kind = model_file_kind(path)
    if kind == MJCF_KIND:  # an MJCF is a robot description by itself; MuJoCo wants .xml
        raise DescriptionError(path, "<file>", "is an MJCF, and MuJoCo reads an MJCF only from "
                               "a .xml file", f"Rename it to {path.stem}.xml and pass that")
    if kind is not None:
        raise NotAMuscleFileError(path, kind)
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise DescriptionError(path, "<file>", f"cannot read YAML ({exc})",
                               "Fix the YAML syntax") from exc
    if not isinstance(raw, dict):
        raise DescriptionError(path, "<file>", "top level is not a mapping",
                               "Write robot, urdf, joints, joint_encoders and muscles keys")
    if "mjcf" in raw:
        if "urdf" in raw:
            raise DescriptionError(path, "mjcf", "both 'urdf' and 'mjcf' are given",
                                   "Keep one: an MJCF's tendons, or a URDF with via points")
        xml = path.parent / _require(raw, "mjcf", str, path, "mjcf")
        if not xml.is_file():
            raise DescriptionError(path, "mjcf", f"MJCF file {xml} not found",
                                   "Give the MJCF path relative to the muscle file")
        return load_mjcf_description(xml, raw, path)
    name = _require(raw, "robot", str, path, "robot")
    urdf_path = _urdf_path(raw, path, package_path)
    text, urdf_joints = _read_urdf(urdf_path, path)
    joints, joint_range = _parse_joints(raw, urdf_joints, path)
    lock = _parse_lock(raw, urdf_joints, joints, path)
    reduced = _reduce(text, joints, lock, urdf_path, path)
    encoders = _require(raw, "joint_encoders", bool, path, "joint_encoders")
    muscles = _parse_muscles(raw, reduced.model, joints, path)
    return RobotDescription(
        name=name, urdf_path=urdf_path.resolve(), muscle_path=path.resolve(), joints=joints,
        joint_range=joint_range, joint_encoders=encoders, muscles=muscles,
        locked=tuple(reduced.locked.items()),
        followers=tuple((k, *v) for k, v in reduced.followers.items()),
    )


def reduced_model(robot: RobotDescription) -> ReducedModel:
    """The pinocchio model of a loaded description (driven joints only, see ``urdf_model``)."""
    return reduce(robot.urdf_path.read_text(), robot.joints, dict(robot.locked))


def _urdf_path(raw: dict, path: Path, package_path: Sequence[Path]) -> Path:
    """``urdf``: relative to the muscle file, absolute, or ``package://pkg/file``."""
    url = _require(raw, "urdf", str, path, "urdf")
    if url.startswith("file://"):
        url = url.removeprefix("file://")
    if not url.startswith("package://"):
        return path.parent / url
    extra = raw.get("package_path", [])
    if isinstance(extra, str):
        extra = [extra]
    if not isinstance(extra, list) or not all(isinstance(p, str) for p in extra):
        raise DescriptionError(path, "package_path", f"expected a list of directories, got "
                               f"{extra!r}", "Write 'package_path: [dir, ...]'")
    search = [*package_path, *(path.parent / p for p in extra), *ros_package_path()]
    return resolve_package_url(url, search, path)  # UrdfError names the file and the fix


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


def _read_urdf(urdf_path: Path, path: Path) -> tuple[str, dict[str, UrdfJoint]]:
    """The URDF text and its joints; a xacro file is refused with how to expand it."""
    if not urdf_path.is_file():
        raise DescriptionError(path, "urdf", f"URDF file {urdf_path} not found",
                               "Give the URDF path relative to the muscle file")
    try:
        text = urdf_path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DescriptionError(path, "urdf", f"cannot read URDF {urdf_path} ({exc})",
                               "Give the path of a readable URDF text file") from exc
    try:
        refuse_xacro(urdf_path, text)
        return text, parse_joints(urdf_path, text)
    except UrdfError as exc:
        raise DescriptionError(path, "urdf", str(exc), "Fix the 'urdf' entry") from exc


def _reduce(text: str, joints: tuple[str, ...], lock: dict[str, float], urdf_path: Path,
            path: Path) -> ReducedModel:
    try:
        return reduce(text, joints, lock)
    except UrdfError as exc:
        raise DescriptionError(path, "urdf", str(exc), "Fix the URDF") from exc
    except Exception as exc:  # pinocchio raises plain RuntimeError/ValueError on parse errors
        raise DescriptionError(path, "urdf", f"cannot parse URDF {urdf_path} ({exc})",
                               "Fix the URDF so pinocchio can load it") from exc


def _parse_lock(raw: dict, urdf: dict[str, UrdfJoint], joints: tuple[str, ...], path: Path
                ) -> dict[str, float]:
    """``lock: {joint: value}``: where a joint the muscles do not drive is held."""
    lock = raw.get("lock", {}) or {}
    if not isinstance(lock, dict):
        raise DescriptionError(path, "lock", f"expected a mapping, got {lock!r}",
                               "Write 'lock: {joint_name: angle_in_rad}'")
    for name, value in lock.items():
        field = f"lock.{name}"
        if name not in urdf or not urdf[name].movable:
            movable = [j.name for j in urdf.values() if j.movable]
            raise DescriptionError(path, field, f"'{name}' is not a movable joint of the URDF "
                                   f"(movable: {movable})", "Use a joint name from the URDF")
        if name in joints:
            raise DescriptionError(path, field, f"'{name}' is driven by the muscles (listed "
                                   "under joints)", "Remove it from 'lock' or from 'joints'")
        if urdf[name].mimic is not None:
            raise DescriptionError(path, field, f"'{name}' is a mimic joint of "
                                   f"'{urdf[name].mimic[0]}'", "Lock its leader instead")
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(value):
            raise DescriptionError(path, field, f"expected a finite number, got {value!r}",
                                   "Give the angle in rad (or position in m)")
        lo, hi = urdf[name].lower, urdf[name].upper
        if not lo <= value <= hi:
            raise DescriptionError(path, field, f"{value} is outside the URDF limits "
                                   f"[{lo:g}, {hi:g}]", "Lock it inside its limits")
    return {k: float(v) for k, v in lock.items()}


def _parse_joints(raw: dict, urdf: dict[str, UrdfJoint], path: Path
                  ) -> tuple[tuple[str, ...], np.ndarray]:
    entries = _require(raw, "joints", list, path, "joints")
    movable = [j.name for j in urdf.values() if j.movable]
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
        joint = urdf[name]
        if joint.type not in ("revolute", "continuous"):
            raise DescriptionError(path, f"{field}.name", f"joint '{name}' is {joint.type}",
                                   "Muscles can drive revolute and continuous joints only")
        if joint.mimic is not None:
            raise DescriptionError(path, f"{field}.name", f"joint '{name}' is a mimic joint "
                                   f"of '{joint.mimic[0]}' and follows it",
                                   f"List its leader '{joint.mimic[0]}' instead")
        rng = _vector(entry.get("range"), 2, path, f"{field}.range")
        lo, hi = joint.lower, joint.upper
        if not rng[0] < rng[1] or rng[0] < lo or rng[1] > hi:
            raise DescriptionError(path, f"{field}.range", f"{list(rng)} is not an increasing "
                                   f"range inside the URDF limits [{lo:g}, {hi:g}]",
                                   "Narrow the sampling range or widen the URDF limit")
        names.append(name)
        ranges.append(rng)
    if not names:
        raise DescriptionError(path, "joints", "no joints listed",
                               "List the joints the muscles drive")
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
        sources = _sources([(entry, "its entry in the muscle file"),
                            (defaults, "the muscle file's defaults")])
        muscles.append(_parse_muscle({**defaults, **entry}, i, model, joints, path, sources))
    _check_unique(muscles, path)
    return tuple(muscles)


def _check_unique(muscles: Sequence[MuscleSpec], path: Path) -> None:
    """Two muscles with one name or one board would be confused on the bus and in files."""
    for key in ("name", "board_id"):
        seen: dict[Any, int] = {}
        for i, m in enumerate(muscles):
            value = getattr(m, key)
            if value in seen:
                raise DescriptionError(path, f"muscles[{i}].{key}",
                                       f"{value!r} is also used by muscles[{seen[value]}]",
                                       f"Give each muscle a unique {key}")
            seen[value] = i


def _parse_muscle(entry: dict, i: int, model, joints: tuple[str, ...], path: Path,
                  sources: dict[str, str]) -> MuscleSpec:
    field = f"muscles[{i}]"
    settings = _muscle_settings(entry, field, path, sources)
    via = _parse_path(_require(entry, "path", list, path, f"{field}.path"), model, joints,
                      path, f"{field}.path")
    return MuscleSpec(path=via, **settings)


def _sources(layers: Sequence[tuple[dict, str]]) -> dict[str, str]:
    """Key -> where its value comes from: the first layer (highest precedence) that sets it."""
    out: dict[str, str] = {}
    for layer, words in layers:
        for key in layer:
            out.setdefault(key, words)
    return out


def _muscle_settings(entry: dict, field: str, path: Path, sources: dict[str, str],
                     fix: str | None = None) -> dict[str, Any]:
    """Name, board, elastic law, limits, sensor calibration and protocol of one muscle entry
    (everything but its path), validated. ``sources``: where each key's value came from, for
    the messages; ``fix``: how to change a limit (default: in this muscle's entry)."""
    name = _require(entry, "name", str, path, f"{field}.name")
    board_id = _require(entry, "board_id", int, path, f"{field}.board_id")
    values: dict[str, float] = {}
    for key in _MUSCLE_FLOATS:
        value = float(_require(entry, key, (int, float), path, f"{field}.{key}"))
        if not math.isfinite(value) or (key in _POSITIVE and value <= 0):
            raise DescriptionError(path, f"{field}.{key}", f"muscle '{name}': {key} {value!r} "
                                   f"({sources.get(key, 'given')}) is "
                                   + ("not a positive finite number" if key in _POSITIVE
                                      else "not finite"),
                                   f"Set {key} to a physically meaningful value")
        values[key] = value
    floor, ceiling = values["f_floor"], values["f_max"]
    if not 0 <= floor < ceiling:
        where = fix or (f"set f_floor (or f_max) in the entry of muscle '{name}' in "
                        f"{path.name}, e.g. '- {{name: {name}, f_floor: {ceiling / 20:.2g}, "
                        "...}'")
        raise DescriptionError(
            path, f"{field}.f_floor",
            f"muscle '{name}': its holding floor f_floor {floor:g} N "
            f"({sources.get('f_floor', 'given')}) is "
            + (f"not below its f_max {ceiling:g} N ({sources.get('f_max', 'given')})"
               if floor >= 0 else "negative"),
            f"The floor must lie in [0, f_max): {where}")
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
    direction = entry.get("direction", 1)
    if isinstance(direction, bool) or direction not in (1, -1):
        raise DescriptionError(path, f"{field}.direction", f"{direction!r} is not 1 or -1",
                               "Write 1 when a positive motor turn reels the wire in, -1 when "
                               "it pays it out (`pimbs check-wiring` tells which)")
    return {"name": name, "board_id": board_id, "protocol": protocol,
            "direction": int(direction), **values}


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


# What a bare MJCF gets for what MuJoCo does not say (docs/mujoco.md lists them): the elastic
# law and sensor calibration of the built-in two-link arm's boards, and a sampling range for a
# hinge without limits. The holding floor follows the muscle: 10 N, or 1/20 of its f_max for
# a muscle weaker than 200 N (a MyoSuite finger muscle declares 5-10 N).
MJCF_MUSCLE_DEFAULTS: dict[str, float] = {
    "K": 1000.0, "f_max": 600.0, "f_floor": 10.0, "counts_per_m": 108650.0,
    "loadcell_n_per_count": 0.25, "loadcell_offset_counts": 2048.0,
}
MJCF_FLOOR_SHARE = 1 / 20  # the default f_floor is at most this share of the muscle's f_max
MJCF_UNLIMITED_RANGE = (-0.5, 0.5)  # rad: sampling range of a hinge with no range
_DEFAULT_FLOOR_WORDS = "PIMBS's default for an MJCF muscle: the smaller of 10 N and f_max/20"


def mjcf_default_floor(f_max: float) -> float:
    """The holding floor (N) of an MJCF muscle whose f_floor nothing sets."""
    return min(MJCF_MUSCLE_DEFAULTS["f_floor"], MJCF_FLOOR_SHARE * f_max)


def load_mjcf_description(xml: Path, raw: dict, path: Path) -> RobotDescription:
    """A description whose muscles are the spatial tendons of the MJCF ``xml``.

    ``raw`` is the muscle file naming it (``mjcf: arm.xml``; ``{}`` for a bare MJCF) and
    ``path`` that file (or the MJCF itself). Driven joints: ``joints`` or every hinge that
    moves on its own (not the follower of an active ``<equality><joint>``), sampled in
    ``range`` or the hinge's own range (``MJCF_UNLIMITED_RANGE`` if it has none). A follower
    whose chain of leaders starts at a driven joint moves with it (``couplings``); every other
    hinge and slide joint is locked at ``lock`` or its ``qpos0``, a follower of a locked
    joint where its equality puts it. Muscles: ``muscles`` (tendons by name, in column order)
    or every spatial tendon in file order, boards numbered 1, 2, ... in that order; f_max is
    the largest tension an actuator on the tendon declares (a force range, a MuJoCo muscle's
    peak force or a motor's control range; times its gear) where there is one, and f_floor
    follows f_max (``mjcf_default_floor``) unless the muscle file sets it.
    """
    from pimbs_calibration.mjcf import MjcfError, read_mjcf

    try:
        arm = read_mjcf(xml)
    except MjcfError as exc:
        where = "" if exc.path.resolve() == path.resolve() else f"{exc.path}: "
        raise DescriptionError(path, "mjcf" if where else "<file>", where + exc.problem,
                               exc.fix) from exc
    couplings = _mjcf_couplings(arm, xml, path)
    hinges = arm.hinge_names()
    if not hinges:
        kinds = sorted({j.type for j in arm.joints})
        what = (f"has no hinge joint (its joints: {', '.join(kinds)})" if arm.joints
                else "has no joint" + ("" if arm.tendons else " and no tendon: nothing a "
                                       "muscle could move"))
        raise DescriptionError(path, "joints", f"{xml} {what}",
                               "Muscles drive hinge joints; add <joint type=\"hinge\">")
    independent = [h for h in hinges if h not in couplings]
    if not independent:
        raise DescriptionError(path, "joints", f"every hinge of {xml.name} follows another "
                               "joint through an <equality><joint>", "Muscles drive joints "
                               "that move on their own: give the model one")
    by_name = {j.name: j for j in arm.joints}
    entries = raw.get("joints", [{"name": n} for n in independent])
    if not isinstance(entries, list) or not entries:
        raise DescriptionError(path, "joints", f"expected a list of joints, got {entries!r}",
                               "Write '- {name: <hinge>, range: [lo, hi]}' per driven joint")
    names, ranges = [], []
    for i, entry in enumerate(entries):
        field = f"joints[{i}]"
        if not isinstance(entry, dict):
            raise DescriptionError(path, field, "expected a mapping {name, range}",
                                   "Write '- {name: <joint>, range: [lo, hi]}'")
        name = _require(entry, "name", str, path, f"{field}.name")
        if name in couplings:
            problem, fix = _follower_words(couplings, name, names)
            raise DescriptionError(path, f"{field}.name", problem, fix)
        if name not in hinges or name in names:
            problem = (f"joint '{name}' listed twice" if name in names else
                       f"'{name}' is not a hinge joint of {xml.name} (hinges: {hinges})")
            raise DescriptionError(path, f"{field}.name", problem,
                                   "List each driven hinge joint once, by its MJCF name")
        joint = by_name[name]
        lo, hi = joint.range if joint.limited else (-UNLIMITED, UNLIMITED)
        default = joint.range if joint.limited else MJCF_UNLIMITED_RANGE
        rng = (_vector(entry["range"], 2, path, f"{field}.range") if "range" in entry
               else np.array(default, dtype=np.float64))
        if not (rng[0] < rng[1] and lo <= rng[0] and rng[1] <= hi):
            raise DescriptionError(path, f"{field}.range", f"{list(rng)} is not an increasing "
                                   f"range inside the joint's range [{lo:g}, {hi:g}] rad",
                                   "Narrow the sampling range or widen the MJCF joint range")
        names.append(name)
        ranges.append(rng)
    locked, followers = _mjcf_lock(raw, arm, names, couplings, path)
    muscles = _mjcf_muscles(raw, arm, path)
    encoders = raw.get("joint_encoders", True)
    if not isinstance(encoders, bool):
        raise DescriptionError(path, "joint_encoders", f"expected true or false, got "
                               f"{encoders!r}", "Write 'joint_encoders: true' or false")
    name = raw.get("robot", arm.name)
    if not isinstance(name, str) or not name:
        raise DescriptionError(path, "robot", f"expected a name, got {name!r}",
                               "Write 'robot: <name>'")
    return RobotDescription(
        name=name, urdf_path=xml.resolve(), muscle_path=path.resolve(), joints=tuple(names),
        joint_range=np.array(ranges, dtype=np.float64).reshape(len(names), 2),
        joint_encoders=encoders, muscles=muscles, locked=locked, mjcf_path=xml.resolve(),
        couplings=followers)


def _mjcf_couplings(arm, xml: Path, path: Path) -> dict[str, JointCoupling]:
    """Follower -> its active joint equality, each after the one moving its leader."""
    try:
        ordered = coupling_order(arm.couplings)
    except CouplingError as exc:
        where = "<file>" if xml.resolve() == path.resolve() else "mjcf"
        raise DescriptionError(path, where, f"{xml.name}: {exc}", "Keep one active "
                               "<equality><joint> per follower joint, leaders not following "
                               "their followers") from exc
    return {c.follower: c for c in ordered}


def _follower_words(couplings: dict[str, JointCoupling], name: str, driven: Sequence[str]
                    ) -> tuple[str, str]:
    """Why a follower can be neither driven nor locked, and what to do instead."""
    c = couplings[name]
    root = root_leader(couplings, name)
    if c.leader is None:
        return (f"'{name}' is held at {c.value(0.0):.4g} by the MJCF's joint equality "
                f"'{c.equality}'", "Leave it out: it cannot move")
    problem = f"'{name}' follows '{c.leader}' through the MJCF's joint equality '{c.equality}'"
    if root is None:
        return problem, "Leave it out: its chain of leaders is held by a joint equality"
    if root in driven:
        return problem, f"Leave it out: it moves with the driven joint '{root}'"
    return problem, f"Drive or lock its leader '{root}' instead"


def _mjcf_lock(raw: dict, arm, driven: list[str], couplings: dict[str, JointCoupling],
               path: Path) -> tuple[tuple[tuple[str, float], ...], tuple[JointCoupling, ...]]:
    """Where every hinge and slide joint that is not driven is held (``lock`` or its qpos0;
    a follower where its equality puts it; ball and free joints stay at qpos0), and the
    couplings that move a joint with a driven one."""
    lock = raw.get("lock", {}) or {}
    if not isinstance(lock, dict):
        raise DescriptionError(path, "lock", f"expected a mapping, got {lock!r}",
                               "Write 'lock: {joint_name: angle_in_rad}'")
    scalar = [j for j in arm.joints if j.type in ("hinge", "slide")]
    free = {j.name: j for j in scalar if j.name not in driven and j.name not in couplings}
    for name, value in lock.items():
        field = f"lock.{name}"
        if name in couplings:
            problem, fix = _follower_words(couplings, name, driven)
            raise DescriptionError(path, field, problem, fix)
        if name not in free:
            raise DescriptionError(path, field, f"'{name}' is not a hinge or slide joint that "
                                   f"is not driven (those: {sorted(free)})",
                                   "Lock a joint of the MJCF that 'joints' does not list")
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(value):
            raise DescriptionError(path, field, f"expected a finite number, got {value!r}",
                                   "Give the angle in rad (or position in m)")
        joint = free[name]
        if joint.limited and not joint.range[0] <= value <= joint.range[1]:
            raise DescriptionError(path, field, f"{value} is outside the joint's range "
                                   f"[{joint.range[0]:g}, {joint.range[1]:g}]",
                                   "Lock it inside its range")
    values = {n: float(lock.get(n, j.qpos0)) for n, j in free.items()}
    followers = moved_by(couplings, driven)
    for c in couplings.values():  # leaders first: a held follower's leader has its value
        if c not in followers:
            values[c.follower] = c.value(values[c.leader] if c.leader is not None else 0.0)
    locked = tuple((j.name, values[j.name]) for j in scalar if j.name in values)
    return locked, tuple(followers)


def _mjcf_muscles(raw: dict, arm, path: Path) -> tuple[MuscleSpec, ...]:
    """The muscles: listed tendons (by name) or every spatial tendon; numbers from the entry,
    then ``defaults``, then the tendon's actuator, then ``MJCF_MUSCLE_DEFAULTS`` (f_floor:
    ``mjcf_default_floor`` of the muscle's f_max)."""
    spatial = arm.spatial_names()
    tendons = {t.name: t for t in arm.tendons}
    if not spatial:
        raise DescriptionError(path, "muscles", f"{arm.path} has no spatial tendon",
                               "Describe each muscle as a <tendon><spatial> through sites")
    defaults = raw.get("defaults", {}) or {}
    if not isinstance(defaults, dict):
        raise DescriptionError(path, "defaults", "expected a mapping",
                               "Write 'defaults: {K: 1000, ...}' or remove it")
    listed = "muscles" in raw
    entries = raw.get("muscles", [{"name": n} for n in spatial])
    if not isinstance(entries, list) or not entries:
        raise DescriptionError(path, "muscles", f"expected a list of tendons, got {entries!r}",
                               "Write '- {name: <spatial tendon>, board_id: 1}' per muscle")
    muscles = []
    for i, entry in enumerate(entries):
        field = f"muscles[{i}]"
        if not isinstance(entry, dict):
            raise DescriptionError(path, field, "expected a mapping",
                                   "Write each muscle as '- {name: <tendon>, board_id: 1}'")
        name = _require(entry, "name", str, path, f"{field}.name")
        if name not in spatial:
            what = ("a fixed tendon (a joint coupling, no path)" if name in tendons
                    else "not a tendon of the MJCF")
            raise DescriptionError(path, f"{field}.name", f"'{name}' is {what} (spatial "
                                   f"tendons: {spatial})", "Name a spatial tendon")
        base = dict(MJCF_MUSCLE_DEFAULTS, board_id=i + 1)
        layers = [(entry, f"its entry in {path.name}"), (defaults, f"the defaults of {path.name}")]
        tendon = tendons[name]
        if tendon.force_limit is not None:
            base["f_max"] = tendon.force_limit
            layers.append(({"f_max": None}, tendon.force_source))
        layers.append((base, "PIMBS's default for an MJCF muscle"))
        settings = {**base, **defaults, **entry}
        sources = _sources(layers)
        if "f_floor" not in entry and "f_floor" not in defaults:
            f_max = settings["f_max"]
            if isinstance(f_max, int | float) and not isinstance(f_max, bool) \
                    and math.isfinite(f_max) and f_max > 0:
                settings["f_floor"] = mjcf_default_floor(float(f_max))
                sources["f_floor"] = _DEFAULT_FLOOR_WORDS
        fix = _limit_fix(name, settings, listed, "f_floor" in defaults, path)
        muscle = _muscle_settings(settings, field if listed else f"tendon {name}", path,
                                  sources, fix)
        muscles.append(MuscleSpec(path=(), **muscle))
    _check_unique(muscles, path)
    return tuple(muscles)


def _limit_fix(name: str, settings: dict, listed: bool, floor_in_defaults: bool, path: Path
               ) -> str:
    """How to give one MJCF muscle other limits: in the muscle file that names the MJCF (an
    entry under ``muscles``), or, for a bare MJCF, in such a file written for it."""
    f_max = settings.get("f_max")
    floor = (f"{f_max / 20:.2g}" if isinstance(f_max, int | float) and not isinstance(f_max, bool)
             and f_max > 0 else "1")
    entry = f"'- {{name: {name}, f_floor: {floor}}}'"
    if path.suffix.lower() == ".xml":
        return (f"write a muscle file naming this MJCF ('mjcf: {path.name}', docs/mujoco.md) "
                f"and set f_floor (or f_max) for it under 'muscles': {entry}")
    where = "its entry under 'muscles'" if listed else "an entry for it under 'muscles'"
    also = (" or take f_floor out of 'defaults' (each muscle then gets the smaller of 10 N and "
            "f_max/20)" if floor_in_defaults else "")
    return f"set f_floor (or f_max) in {where} of {path.name}: {entry}{also}"
