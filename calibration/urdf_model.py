"""A URDF as shipped, reduced to the joints the muscles drive.

A lab's robot description is exported from CAD or taken from a ROS description package: it
has more movable joints than the muscles drive (fingers, wrist), ``continuous`` joints, mimic
joints, meshes behind ``package://`` paths. PIMBS needs none of the geometry and only the
driven joints, so the URDF is read as it is and

* meshes (``visual``/``collision``) are dropped before pinocchio sees the file: no path in it
  is ever resolved;
* ``continuous`` joints become revolute joints without limits (one angle, not cos/sin);
* every movable joint the muscle file does not drive is locked (pinocchio's
  ``buildReducedModel``) at 0 or at the value the muscle file gives; its links and their
  masses stay, rigidly attached to the last driven joint before them;
* a mimic joint follows its leader: locked with it, or moved by it (``q = m·θ + c``), which
  ``ReducedModel.S``/``offset`` express so the arm model maps driven angles to the full pose.
"""

from __future__ import annotations

import contextlib
import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pimbs_calibration.xacro_check import live_xacro

UNLIMITED = 1e6  # rad: the limit written for a continuous joint (pinocchio needs a number)
_MOVABLE = ("revolute", "continuous", "prismatic")


class UrdfError(ValueError):
    """The URDF cannot be used; the message names the file and what to do."""


@dataclass(frozen=True)
class UrdfJoint:
    """One joint as the URDF declares it."""

    name: str
    type: str
    parent: str
    child: str
    lower: float  # -inf for continuous joints (and joints without a limit tag)
    upper: float
    mimic: tuple[str, float, float] | None  # (leader, multiplier, offset)

    @property
    def movable(self) -> bool:
        return self.type in _MOVABLE


@dataclass
class ReducedModel:
    """Pinocchio model of the driven joints and how driven angles set its configuration.

    ``q = S @ theta + offset``: columns of ``S`` are driven joints, rows the reduced model's
    joints (driven ones and mimic joints that follow them); all are one-angle joints.
    """

    model: object  # pinocchio.Model
    S: np.ndarray  # (nq, N)
    offset: np.ndarray  # (nq,)
    locked: dict[str, float]  # joint -> value it is locked at
    followers: dict[str, tuple[str, float, float]]  # mimic joint -> (driven leader, m, c)


def refuse_xacro(urdf_path: Path, text: str) -> None:
    """A file with live xacro is a macro program, not a URDF: say how to expand it.

    A declared ``xmlns:xacro`` or xacro left in comments (what xacro's own output keeps) is
    not refused: see :mod:`xacro_check`.
    """
    live = live_xacro(text)
    if live is not None:
        out = urdf_path.name.removesuffix(".xacro")
        out = out if out.endswith(".urdf") else out + ".urdf"
        raise UrdfError(f"{urdf_path} is a xacro file ({live}), not a URDF; expand it first "
                        f"with "
                        f"`xacro {urdf_path.name} > {out}` (ROS's xacro, or `pip install "
                        f"xacro`) and point 'urdf' at {out}")


def parse_joints(urdf_path: Path, text: str) -> dict[str, UrdfJoint]:
    """Joints of the URDF text, by name, in file order."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise UrdfError(f"cannot parse URDF {urdf_path}: not valid XML ({exc})") from exc
    if root.tag != "robot":
        raise UrdfError(f"{urdf_path}: top element is <{root.tag}>, not <robot>; "
                        "give the path of a URDF file")
    joints: dict[str, UrdfJoint] = {}
    for el in root.findall("joint"):
        name, kind = el.get("name", ""), el.get("type", "")
        limit, mimic = el.find("limit"), el.find("mimic")
        lo, hi = -math.inf, math.inf
        if limit is not None and kind in ("revolute", "prismatic"):
            lo, hi = float(limit.get("lower", 0)), float(limit.get("upper", 0))
        parent, child = el.find("parent"), el.find("child")
        joints[name] = UrdfJoint(
            name=name, type=kind, parent=parent.get("link", "") if parent is not None else "",
            child=child.get("link", "") if child is not None else "", lower=lo, upper=hi,
            mimic=None if mimic is None else (mimic.get("joint", ""),
                                              float(mimic.get("multiplier", 1.0)),
                                              float(mimic.get("offset", 0.0))))
    return joints


def link_masses(text: str) -> dict[str, float]:
    """Mass (kg) of every link that declares one."""
    masses = {}
    for link in ET.fromstring(text).findall("link"):
        mass = link.find("inertial/mass")
        if mass is not None:
            masses[link.get("name", "")] = float(mass.get("value", 0.0))
    return masses


def link_centres(text: str) -> dict[str, np.ndarray]:
    """Centre of mass (3,) of every link that declares an inertial origin, in its frame."""
    centres = {}
    for link in ET.fromstring(text).findall("link"):
        origin = link.find("inertial/origin")
        if origin is not None:
            centres[link.get("name", "")] = np.array(
                [float(v) for v in origin.get("xyz", "0 0 0").split()])
    return centres


def prepared_xml(text: str, rename: Mapping[str, str] | None = None) -> str:
    """The URDF pinocchio reads: no geometry, continuous joints as unlimited revolute ones,
    mimic tags removed (``reduce`` resolves them), joints named in ``rename`` renamed."""
    root = ET.fromstring(text)
    for joint in root.findall("joint"):
        if rename and joint.get("name") in rename:
            joint.set("name", rename[joint.get("name", "")])
    for link in root.findall("link"):
        for tag in ("visual", "collision"):
            for el in link.findall(tag):
                link.remove(el)
    for joint in root.findall("joint"):
        for el in joint.findall("mimic"):
            joint.remove(el)
        if joint.get("type") == "continuous":
            joint.set("type", "revolute")
            for el in joint.findall("limit"):
                joint.remove(el)
            ET.SubElement(joint, "limit", lower=str(-UNLIMITED), upper=str(UNLIMITED),
                          effort="0", velocity="0")
    # Gazebo/transmission blocks may reference plugins and files: pinocchio ignores them.
    return ET.tostring(root, encoding="unicode")


def resolve_mimic(joints: Mapping[str, UrdfJoint], name: str) -> tuple[str, float, float]:
    """(root leader, multiplier, offset) of a mimic chain: q_name = m·q_leader + c."""
    m, c, seen = 1.0, 0.0, {name}
    while joints[name].mimic is not None:
        leader, mult, off = joints[name].mimic
        if leader not in joints:
            raise UrdfError(f"mimic joint '{name}' follows '{leader}', which is not a joint")
        if leader in seen:
            raise UrdfError(f"mimic joints {sorted(seen)} follow each other in a loop")
        seen.add(leader)
        m, c = m * mult, c * mult + off
        name = leader
    return name, m, c


def reduce(text: str, driven: Sequence[str], lock: Mapping[str, float]) -> ReducedModel:
    """Pinocchio model of ``text`` with every movable joint but ``driven`` (and their
    mimics) locked at ``lock[name]`` or 0, clipped into the joint's limits."""
    import pinocchio as pin  # lazy: heavy import

    joints = parse_joints(Path("<urdf>"), text)
    rename = _lock_names(text, joints)
    full = pin.buildModelFromXML(prepared_xml(text, rename))
    q_ref = pin.neutral(full)
    leaders = _leaders(joints)
    locked: dict[str, float] = {}
    followers: dict[str, tuple[str, float, float]] = {}
    for j in joints.values():
        if not j.movable or j.name in driven:
            continue
        if j.name in leaders and leaders[j.name][0] in driven:
            followers[j.name] = leaders[j.name]
            continue
        if j.name in leaders:
            leader, m, c = leaders[j.name]
            value = m * _lock_value(joints[leader], lock) + c
        else:
            value = _lock_value(j, lock)
        locked[j.name] = value
        q_ref[full.joints[full.getJointId(rename.get(j.name, j.name))].idx_q] = value
    lock_ids = [full.getJointId(rename.get(name, name)) for name in locked]
    model = pin.buildReducedModel(full, lock_ids, q_ref) if lock_ids else full
    _restore_names(model, rename)
    S = np.zeros((model.nq, len(driven)))
    offset = np.zeros(model.nq)
    for k, name in enumerate(driven):
        S[model.joints[model.getJointId(name)].idx_q, k] = 1.0  # names restored above
    for name, (leader, m, c) in followers.items():
        iq = model.joints[model.getJointId(name)].idx_q
        S[iq, list(driven).index(leader)] = m
        offset[iq] = c
    return ReducedModel(model=model, S=S, offset=offset, locked=locked, followers=followers)


def _leaders(joints: Mapping[str, UrdfJoint]) -> dict[str, tuple[str, float, float]]:
    """(leader, multiplier, offset) of every movable mimic joint whose chain resolves.

    A chain that names no joint or loops (a shipped hand URDF's mimic names a joint of
    another prefix) cannot follow anything: such a joint is locked like any joint the
    muscles do not drive. A driven joint is never a mimic (the description refuses that).
    """
    leaders = {}
    for j in joints.values():
        if j.movable and j.mimic is not None:
            with contextlib.suppress(UrdfError):
                leaders[j.name] = resolve_mimic(joints, j.name)
    return leaders


def _lock_names(text: str, joints: Mapping[str, UrdfJoint]) -> dict[str, str]:
    """Stand-in names for the movable joints that share their name with a link.

    Pinocchio's ``buildReducedModel`` looks joint frames up by name alone and stops at
    "Several frames match the filter" when a link has the same name (ANYmal C and SO-100
    ship such URDFs). The joints are renamed for pinocchio; ``_restore_names`` gives the
    driven ones their own names back once the model is reduced.
    """
    links = {el.get("name", "") for el in ET.fromstring(text).findall("link")}
    taken = links | set(joints)
    rename = {}
    for name, joint in joints.items():
        if joint.movable and name in links:
            new = f"{name}__locked"
            while new in taken:
                new += "_"
            rename[name] = new
            taken.add(new)
    return rename


def _restore_names(model, rename: Mapping[str, str]) -> None:
    """The URDF's names for the joints (and joint frames) ``_lock_names`` renamed."""
    back = {new: old for old, new in rename.items()}
    for jid, name in enumerate(model.names):
        if name in back:
            model.names[jid] = back[name]
    for frame in model.frames:
        if frame.name in back:
            frame.name = back[frame.name]


def _lock_value(joint: UrdfJoint, lock: Mapping[str, float]) -> float:
    return float(np.clip(lock.get(joint.name, 0.0), joint.lower, joint.upper))


def resolve_package_url(url: str, search_path: Iterable[Path], origin: Path) -> Path:
    """``package://pkg/rest`` -> a file, looking in each search directory (a package
    directory itself, a directory holding it, or a ROS workspace below it)."""
    pkg, _, rest = url.removeprefix("package://").partition("/")
    roots = [Path(p) for p in search_path]
    for root in roots:
        for candidate in _package_dirs(root, pkg):
            if (candidate / rest).is_file():
                return candidate / rest
    where = ", ".join(str(r) for r in roots) or "nowhere (ROS_PACKAGE_PATH is not set)"
    raise UrdfError(f"{origin}: field 'urdf': {url} not found: package '{pkg}' with "
                    f"{rest} was looked for in {where}. Set ROS_PACKAGE_PATH (or list the "
                    "directory under 'package_path' in the muscle file) to the directory that "
                    f"holds the package '{pkg}'")


def _package_dirs(root: Path, pkg: str, depth: int = 4) -> Iterable[Path]:
    """Directories of package ``pkg`` at or below ``root`` (by name or by package.xml)."""
    if not root.is_dir():
        return
    if root.name == pkg:
        yield root
    for current, dirs, files in os.walk(root):
        level = len(Path(current).relative_to(root).parts)
        if level >= depth:
            dirs[:] = []
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        here = Path(current)
        if here != root and here.name == pkg:
            yield here
        elif "package.xml" in files and f"<name>{pkg}</name>" in _read(here / "package.xml"):
            yield here


def _read(path: Path) -> str:
    try:
        return path.read_text(errors="replace")
    except OSError:
        return ""


def ros_package_path() -> list[Path]:
    """Directories listed in ``ROS_PACKAGE_PATH`` (colon separated, like ROS)."""
    return [Path(p) for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p]
