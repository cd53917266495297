"""A seeded population of tendon-driven arms: robot descriptions PIMBS loads, each drivable.

Learning and diagnosis are judged on arms nobody tuned them on, so the arms are drawn, not
written: ``make_arm(seed, family, folder)`` writes one arm's files and returns an
:class:`ArmSpec` (paths, shape, every drawn number, JSON-able). Two families, one skeleton:

* ``"viapoint"``: a URDF and a ``.muscles.yaml`` whose muscles run through via points
  (pinocchio + straight segments, ``pimbs_arm.backends.viapoints``);
* ``"mujoco"``: an MJCF whose muscles are spatial tendons through sites, on some arms
  wrapping cylinder and sphere pulleys at the joints and, on some, split by a
  ``<pulley divisor="2">`` into two heads (``pimbs_arm.backends.mujoco_tendons``: MuJoCo
  measures them). The joints carry damping and armature so that MuJoCo can also be the
  plant the arm is recorded on.

What is drawn from the seed (SI units): 2–5 hinge joints, hanging down at θ = 0, about y
(planar arms) or about x, y, z and oblique axes (spatial arms); link lengths 0.1–0.4 m,
masses 0.2–2.5 kg (proximal links the heavier), centres of mass 35–60 % down each link;
sampling ranges ±0.3–0.9 rad (URDF/MJCF limits 0.3 rad beyond); per joint an antagonist
pair, and on half the arms two more muscles (spanning two joints, or a third on one joint);
the levers (moment arms at θ = 0) on a joint's two sides sum to totals that differ by up to
the factor the ATL floors allow (``_lever_ratio``), sized to the gravity torque the joint
must hold; per muscle K 300–2000 /m
(f = exp(K·Δn) − 1) and f_max 100–600 N (spread ±10 % around the arm's value).

Every arm is **checked drivable** before it is returned: it loads as an ``ArmModel`` (which
checks both ways at the centre of its ranges), every driven joint turns both ways at every
pose ``pimbs_arm.routing.check_poses`` checks (as ``pimbs simulate`` demands), and
``pimbs_arm.poses.plan_poses`` plans ``samples`` poses of seed ``seed`` for both the AL and
the ATL map with at most ``MAX_REPLACED_SHARE`` of them replaced. A draw that fails is drawn
again from the sub-seed ``[seed, family, try]``; the spec records how many tries it took.
The number of joints is drawn once from the seed and kept over the tries, so the population's
shapes stay spread over 2–5 joints.
"""

from __future__ import annotations

import itertools
import shutil
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
import scipy.linalg
import yaml

from pimbs_arm.model import ArmModel, InfeasiblePoseError, sample_poses
from pimbs_arm.poses import PLAN_CEILING, atl_floor_range, feasible, plan_poses
from pimbs_arm.routing import both_ways_problem, check_poses, routing_report
from pimbs_calibration.description import DescriptionError

FAMILIES = ("viapoint", "mujoco")
DOF = (2, 5)
LINK_LENGTH = (0.1, 0.4)    # m
LINK_MASS = (0.2, 2.5)      # kg
HALF_RANGE = (0.3, 0.9)     # rad, sampling range ±
LIMIT_MARGIN = 0.3          # rad, hard limits beyond the sampling range
K_RANGE = (300.0, 2000.0)   # 1/m
F_MAX = (100.0, 600.0)      # N
F_FLOOR = 10.0              # N, holding floor of every muscle
LEVER = (0.012, 0.08)       # m: the smallest and largest moment arm a crossing gets
GRAVITY_QUANTILE = 0.9      # levers hold this quantile of a joint's |gravity torque| ...
FLOOR_QUANTILE = 0.5        # ... against an antagonist at this quantile of the ATL floors
PLANAR_SHARE = 0.35         # of arms whose hinges are all about y
EXTRA_MUSCLES_SHARE = 0.5   # of arms with two muscles beyond the antagonist pairs ...
THIRD_MUSCLE_SHARE = 1 / 3  # ... each a third muscle on one joint, else spanning two joints
WRAPPING_SHARE = 0.65       # of MuJoCo arms whose crossings wrap pulleys (cylinders, spheres)
TWO_HEADED_SHARE = 0.35     # of MuJoCo arms with a two-headed muscle (pulley divisor 2)
RING_S = 0.15               # s: MuJoCo arms' joint damping makes every motion decay this fast
TIMESTEP = 0.002            # s, MuJoCo's step on these arms
MAX_TRIES = 200
PRECHECK_POSES = 40         # poses of the plan's sequence tried before the full plan
MAX_REPLACED_SHARE = 0.1    # of planned poses that may be replacement draws
BOARD = {"counts_per_m": 108650.0, "loadcell_n_per_count": 0.25,
         "loadcell_offset_counts": 2048.0}  # the built-in arm's boards
_LINK_RADIUS = 0.03  # m, for the links' inertia about their own axis
_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


class NotDrivable(RuntimeError):
    """No draw of a seed gave a drivable arm within ``MAX_TRIES`` (message says why)."""


@dataclass(frozen=True)
class ArmSpec:
    """One drawn arm: where its files are and what was drawn (``params``, JSON-able)."""

    seed: int
    family: str
    name: str
    description: Path        # what ``load_robot`` / ``ArmModel.load`` take
    files: tuple[Path, ...]  # every file written
    dof: int
    joints: tuple[str, ...]
    muscles: tuple[str, ...]
    params: dict[str, Any]
    tries: int               # draws until one was drivable (1: the first)
    replaced: dict[str, int]  # replaced poses of the checked plans, per map

    @property
    def n_muscles(self) -> int:
        return len(self.muscles)

    @property
    def mjcf(self) -> Path | None:
        """The MJCF of a MuJoCo-family arm (the plant it is recorded on, unless changed)."""
        return next((f for f in self.files if f.suffix == ".xml"), None)

    def load(self) -> ArmModel:
        return ArmModel.load(self.description)

    def to_json(self) -> dict[str, Any]:
        return {"seed": self.seed, "family": self.family, "name": self.name,
                "description": str(self.description), "files": [str(f) for f in self.files],
                "dof": self.dof, "joints": list(self.joints), "muscles": list(self.muscles),
                "params": self.params, "tries": self.tries, "replaced": self.replaced}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> ArmSpec:
        return cls(seed=d["seed"], family=d["family"], name=d["name"],
                   description=Path(d["description"]), files=tuple(Path(f) for f in d["files"]),
                   dof=d["dof"], joints=tuple(d["joints"]), muscles=tuple(d["muscles"]),
                   params=d["params"], tries=d["tries"], replaced=d["replaced"])


def arm_name(seed: int) -> str:
    return f"arm{seed:03d}"


def make_arm(seed: int, family: str, folder: str | Path, samples: int = 230) -> ArmSpec:
    """Draw arm ``seed`` of ``family``, write its files into ``folder`` and check it drivable
    (plans of ``samples`` poses, seed ``seed``, both maps). Deterministic: the same seed
    writes the same bytes. Raises ``NotDrivable`` if no draw passes."""
    if family not in FAMILIES:
        raise ValueError(f"family must be one of {', '.join(FAMILIES)}, not {family!r}")
    folder = Path(folder)
    dof = int(np.random.default_rng([seed, 0]).integers(DOF[0], DOF[1] + 1))
    why: list[str] = []
    for attempt in range(1, MAX_TRIES + 1):
        rng = np.random.default_rng([seed, FAMILIES.index(family) + 1, attempt])
        params = _draw(rng, dof, family)
        if params is None:
            why.append("gravity beyond the levers")
            continue
        work = folder / f".try-{arm_name(seed)}"
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True)
        description = _write(params, family, arm_name(seed), work)
        problem, replaced = _drivable(description, samples, seed)
        if problem is None:
            files = []
            for f in sorted(work.iterdir()):
                target = folder / f.name
                f.replace(target)
                files.append(target)
            work.rmdir()
            arm = ArmModel.load(folder / description.name)
            return ArmSpec(seed=seed, family=family, name=arm_name(seed),
                           description=folder / description.name, files=tuple(files),
                           dof=dof, joints=tuple(arm.joints), muscles=tuple(arm.muscles),
                           params=params, tries=attempt, replaced=replaced)
        shutil.rmtree(work, ignore_errors=True)
        why.append(problem)
    raise NotDrivable(f"{arm_name(seed)} ({family}, {dof} joints): no drivable draw in "
                      f"{MAX_TRIES} tries; last reasons: {'; '.join(why[-3:])}")


def population(seeds: Iterable[int], folder: str | Path, families: dict[int, str] | None = None,
               samples: int = 230) -> list[ArmSpec]:
    """``make_arm`` for every seed, each in ``folder/<name>``; ``families`` maps a seed to its
    family (default: ``family_of``)."""
    folder = Path(folder)
    out = []
    for seed in seeds:
        family = (families or {}).get(seed) or family_of(seed)[0]
        out.append(make_arm(seed, family, folder / arm_name(seed), samples))
    return out


def family_of(seed: int) -> tuple[str, str]:
    """(family, simulator) of arm ``seed`` in the fixed population layout: seeds 2k and 2k+1
    (one development, one judging arm) share it; k mod 4 = 0, 1: via points on PIMBS's
    simulator; 2: MJCF on PIMBS's simulator; 3: MJCF on MuJoCo as the plant. So 40 arms are
    20 / 10 / 10, and each half holds 10 / 5 / 5."""
    k = (seed // 2) % 4
    return ("viapoint", "ours") if k < 2 else ("mujoco", "ours" if k == 2 else "mujoco")


def split_of(seed: int) -> str:
    """The fixed split: even seeds develop, odd seeds judge."""
    return "dev" if seed % 2 == 0 else "judge"


# ------------------------------------------------------------------------------ drawing
def _draw(rng: np.random.Generator, dof: int, family: str) -> dict[str, Any] | None:
    """Every number of one arm, or None when its gravity needs levers beyond ``LEVER``."""
    planar = bool(rng.random() < PLANAR_SHARE)
    joints = []
    for k in range(dof):
        if planar:
            kind = "y"
        else:
            kind = str(rng.choice(["y", "x", "z", "oblique"], p=[0.4, 0.3, 0.15, 0.15]))
        if kind == "oblique":
            a = rng.normal(size=3)
            axis = a / np.linalg.norm(a)
        else:
            axis = np.array(_AXES[kind])
        half = float(rng.uniform(*HALF_RANGE))
        joints.append({"name": f"j{k + 1}_{kind[0] if kind != 'oblique' else 'o'}",
                       "axis": _rounded(axis), "half_range": round(half, 4)})
    masses = np.sort(rng.uniform(*LINK_MASS, dof))[::-1]
    links = []
    for k in range(dof):
        length = float(rng.uniform(*LINK_LENGTH))
        links.append({"name": f"link{k + 1}", "length": round(length, 4),
                      "mass": round(float(masses[k]), 4),
                      "com": round(float(rng.uniform(0.35, 0.6)) * length, 4)})
    f_arm = float(rng.uniform(*F_MAX))
    bound, torque = _gravity_torque(joints, links)
    f_min_arm = f_arm * 0.9  # the weakest muscle's f_max is at least this (±10 % spread)
    low, top = atl_floor_range_of(f_min_arm)
    floor = low + FLOOR_QUANTILE * (top - low)
    room = PLAN_CEILING * f_min_arm
    muscles = _draw_muscles(rng, dof)
    for k in range(dof):
        ratio = float(rng.uniform(1.0, _lever_ratio(room, top)))
        need = torque[k] / max(room - floor * ratio, 1e-9) * float(rng.uniform(1.0, 1.3))
        if not _size_levers(muscles, k, max(need, LEVER[0]), ratio, int(rng.choice([1, -1]))):
            return None
    for m in muscles:
        m["K"] = round(float(rng.uniform(*K_RANGE)), 1)
        m["f_max"] = round(float(np.clip(f_arm * rng.uniform(0.9, 1.1), *F_MAX)), 1)
    params: dict[str, Any] = {"dof": dof, "planar": planar, "joints": joints, "links": links,
                              "f_max_arm": round(f_arm, 1), "gravity_bound": _rounded(bound),
                              "muscles": muscles}
    if family == "mujoco":
        _draw_mujoco(rng, params)
    return params


def atl_floor_range_of(f_max_min: float) -> tuple[float, float]:
    """The ATL floors' range of an arm whose weakest muscle holds ``f_max_min`` N (the rule
    of ``pimbs_arm.poses.atl_floor_range``)."""
    from types import SimpleNamespace

    return atl_floor_range(SimpleNamespace(f_max=np.array([f_max_min])))


def _lever_ratio(room: float, floor_top: float) -> float:
    """Largest ratio of antagonist levers the ATL floors allow: the smaller lever's muscle
    must balance the larger one at the top floor with room to spare for gravity."""
    return float(np.clip(0.85 * room / floor_top, 1.0, 1.6))


def _draw_muscles(rng: np.random.Generator, dof: int) -> list[dict[str, Any]]:
    """The routing, levers still relative (``weight``): an antagonist pair per joint and, on
    half the arms, two more muscles, each spanning two neighbouring joints or (one in three)
    a third muscle on one joint. So an arm has 2·dof or 2·dof + 2 muscles: few shapes, many
    arms per shape to train stacked."""
    muscles: list[dict[str, Any]] = []

    def crossing(k: int, side: int, weight: float) -> dict[str, Any]:
        return {"joint": k, "side": side, "weight": weight}

    def side() -> int:
        return int(rng.choice([1, -1]))

    for k in range(dof):
        for s in (1, -1):
            muscles.append({"crossings": [crossing(k, s, 1.0)]})
    for _ in range(2 if rng.random() < EXTRA_MUSCLES_SHARE else 0):
        if rng.random() < THIRD_MUSCLE_SHARE:
            k = int(rng.integers(dof))
            muscles.append({"crossings": [crossing(k, side(), float(rng.uniform(0.6, 1.0)))]})
        else:
            k = int(rng.integers(dof - 1))
            muscles.append({"crossings": [
                crossing(k, side(), float(rng.uniform(0.6, 1.0))),
                crossing(k + 1, side(), float(rng.uniform(0.6, 1.0)))]})
    for i, m in enumerate(muscles):
        m["name"] = f"m{i}"
        m["origin"] = round(float(rng.uniform(0.3, 0.7)), 3)     # share up the parent link
        m["insertion"] = round(float(rng.uniform(0.3, 0.7)), 3)  # share down the child link
    return muscles


def _size_levers(muscles: list[dict[str, Any]], k: int, total: float, ratio: float,
                 big: int) -> bool:
    """Give joint k's crossings their levers (m): the levers on each side sum to ``total``
    on one and ``ratio``·``total`` on the side ``big``, so the ATL floors of all its muscles
    nearly cancel (a floor adds torque only through the imbalance) and either side alone holds
    the joint's gravity. False if a lever would exceed ``LEVER``."""
    here = [c for m in muscles for c in m["crossings"] if c["joint"] == k]
    for side in (1, -1):
        mine = [c for c in here if c["side"] == side]
        scale = (ratio if side == big else 1.0) * total / sum(c["weight"] for c in mine)
        for c in mine:
            c["lever"] = round(max(LEVER[0], scale * c.pop("weight")), 4)
            if c["lever"] > LEVER[1]:
                return False
    return True


def _draw_mujoco(rng: np.random.Generator, params: dict[str, Any]) -> None:
    """Wrapping per joint, two-headed muscles, armature and the damping that settles it."""
    dof = params["dof"]
    wrapping = bool(rng.random() < WRAPPING_SHARE)
    params["wrap"] = [str(rng.choice(["cylinder", "sphere", "none"], p=[0.55, 0.25, 0.2]))
                      if wrapping else "none" for _ in range(dof)]
    heads = [0] * len(params["muscles"])
    if rng.random() < TWO_HEADED_SHARE:
        spanning = [i for i, m in enumerate(params["muscles"]) if len(m["crossings"]) == 2]
        pick = spanning or [int(rng.integers(len(params["muscles"])))]
        for i in pick:
            heads[i] = 1
    for m, h in zip(params["muscles"], heads, strict=True):
        if h:  # the last crossing splits into two heads, levers apart, the mean kept
            last = m["crossings"][-1]
            spread = float(rng.uniform(0.15, 0.35))
            last["heads"] = [round(last["lever"] * (1 - spread), 4),
                             round(last["lever"] * (1 + spread), 4)]
    params["armature"] = [round(float(rng.uniform(0.002, 0.01)), 4) for _ in range(dof)]
    params["damping"] = _rounded(_damping(params))
    params["timestep"] = TIMESTEP


# ------------------------------------------------------------------------ the skeleton
def _urdf(name: str, params: dict[str, Any]) -> str:
    """The skeleton as a URDF: base_link, then link k on joint k, hanging along −z."""
    root = ET.Element("robot", name=name)
    ET.SubElement(root, "link", name="base_link")
    parent, drop = "base_link", 0.0
    for joint, link in zip(params["joints"], params["links"], strict=True):
        el = ET.SubElement(root, "link", name=link["name"])
        inertial = ET.SubElement(el, "inertial")
        ET.SubElement(inertial, "origin", xyz=f"0 0 {-link['com']:g}", rpy="0 0 0")
        ET.SubElement(inertial, "mass", value=f"{link['mass']:g}")
        ixx, izz = _rod_inertia(link)
        ET.SubElement(inertial, "inertia", ixx=f"{ixx:.6g}", ixy="0", ixz="0",
                      iyy=f"{ixx:.6g}", iyz="0", izz=f"{izz:.6g}")
        j = ET.SubElement(root, "joint", name=joint["name"], type="revolute")
        ET.SubElement(j, "parent", link=parent)
        ET.SubElement(j, "child", link=link["name"])
        ET.SubElement(j, "origin", xyz=f"0 0 {-drop:g}", rpy="0 0 0")
        ET.SubElement(j, "axis", xyz=" ".join(f"{v:g}" for v in joint["axis"]))
        limit = joint["half_range"] + LIMIT_MARGIN
        ET.SubElement(j, "limit", lower=f"{-limit:g}", upper=f"{limit:g}", effort="200",
                      velocity="5")
        parent, drop = link["name"], link["length"]
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _rod_inertia(link: dict[str, Any]) -> tuple[float, float]:
    """A rod's inertia about its centre of mass: across (ixx = iyy) and along (izz)."""
    m, length = link["mass"], link["length"]
    return m * (length ** 2 / 12 + _LINK_RADIUS ** 2 / 4), m * _LINK_RADIUS ** 2 / 2


def _pin_model(params: dict[str, Any]) -> pin.Model:
    return pin.buildModelFromXML(_urdf("skeleton", params))


def _corners(params: dict[str, Any], n_random: int = 0, seed: int = 0) -> np.ndarray:
    half = np.array([j["half_range"] for j in params["joints"]])
    poses = [np.zeros(len(half))]
    poses += [np.array(c) * half for c in itertools.product(*[(-1.0, 1.0)] * len(half))]
    if n_random:
        poses += list(np.random.default_rng(seed).uniform(-half, half, (n_random, len(half))))
    return np.array(poses)


def _gravity_torque(joints: list[dict], links: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """(N,) each joint's largest |gravity torque| over the corners and 200 random poses of
    its ranges, and (N,) its ``GRAVITY_QUANTILE`` over the random poses (N·m)."""
    params = {"joints": joints, "links": links}
    model = _pin_model(params)
    data = model.createData()
    poses = _corners(params, 200)
    tau = np.abs([pin.computeGeneralizedGravity(model, data, q) for q in poses])
    return tau.max(axis=0), np.quantile(tau[-200:], GRAVITY_QUANTILE, axis=0)


def _damping(params: dict[str, Any]) -> np.ndarray:
    """Joint damping in proportion to each joint's largest inertia (armature included), scaled
    so that every motion decays within ``RING_S`` at the centre and corners of the ranges (the
    bound ``pimbs_hw.mock.mujoco_plant.ringing`` checks: 2 / the smallest eigenvalue of
    M⁻¹D)."""
    model = _pin_model(params)
    data = model.createData()
    armature = np.diag(params["armature"])
    inertias = [pin.crba(model, data, q) + armature for q in _corners(params)]
    inertias = [np.triu(m) + np.triu(m, 1).T for m in inertias]  # crba fills the upper half
    shape = np.max([np.diag(m) for m in inertias], axis=0)
    worst = min(float(scipy.linalg.eigh(np.diag(shape), m, eigvals_only=True).min())
                for m in inertias)
    return shape * 2.0 / (RING_S * worst)


# ---------------------------------------------------------------------- muscle geometry
def _frame(axis: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) for a wire crossing a hinge about ``axis``: it runs along v at offset u, so its
    moment arm is the offset (v = axis × u). v points down the link (−z side up) where the
    axis allows; about a vertical axis the wire runs across, around it."""
    a = np.asarray(axis, float)
    helper = np.array([0.0, 0.0, 1.0]) if abs(a[2]) < 0.95 else np.array([1.0, 0.0, 0.0])
    u = np.cross(helper, a)
    u /= np.linalg.norm(u)
    v = np.cross(a, u)
    if v[2] < -1e-9 or (abs(v[2]) <= 1e-9 and v.sum() < 0):
        u, v = -u, -v
    return u, v


def _joint_origin(params: dict[str, Any], k: int) -> np.ndarray:
    """Joint k's position in its parent link's frame."""
    return np.array([0.0, 0.0, -params["links"][k - 1]["length"] if k else 0.0])


def _link(params: dict[str, Any], k: int) -> str:
    """The link carried by joint k (k = -1: the base)."""
    return "base_link" if k < 0 else params["links"][k]["name"]


def _crossing_points(params: dict[str, Any], c: dict[str, Any], lever: float, wrap: str
                     ) -> tuple[tuple[str, np.ndarray], tuple[str, np.ndarray]]:
    """The wire's last point on the parent link and first on the child link at a crossing.

    Without wrapping, two via points ``lever`` off the axis and 0.6·lever along the wire
    on either side (a pulley-like wrap: the moment arm stays near the lever over the range).
    With a wrapping geom of radius ``lever``, two sites 0.7·lever off the axis and well
    along the wire, so the straight line between them cuts the pulley and the tendon wraps.
    """
    k, side = c["joint"], c["side"]
    u, v = _frame(params["joints"][k]["axis"])
    off, along = ((0.7 * lever, max(3 * lever, 0.04)) if wrap != "none"
                  else (lever, 0.6 * lever))
    near = side * off * u
    return ((_link(params, k - 1), _joint_origin(params, k) + near + along * v),
            (_link(params, k), near - along * v))


def _paths(params: dict[str, Any], wraps: list[str]) -> list[list[tuple]]:
    """Each muscle's path as items ("site", link, point) | ("wrap", joint, side, lever) |
    ("pulley",), in order from origin to insertion."""
    out = []
    for m in params["muscles"]:
        cs = m["crossings"]
        first, last = cs[0]["joint"], cs[-1]["joint"]
        items: list[tuple] = []
        parent_len = params["links"][first - 1]["length"] if first else 0.1
        for i, c in enumerate(cs):
            heads = c.get("heads")
            wrap = wraps[c["joint"]] if not heads else "none"
            (pl, pp), (cl, cp) = _crossing_points(params, c, c["lever"], wrap)
            if i == 0:  # the origin: up the parent link from the crossing
                items.append(("site", pl, pp + np.array([0, 0, m["origin"] * parent_len])))
            if heads:  # a pulley up the parent link, then one branch per head
                items.append(("site", pl, pp + np.array([0, 0, 0.02])))
                tip = items[-1]
                for lever in heads:
                    (hl, hp), (cl2, cp2) = _crossing_points(params, c, lever, "none")
                    items += [("pulley",), tip, ("site", hl, hp), ("site", cl2, cp2),
                              ("site", cl2, cp2 - np.array(
                                  [0, 0, m["insertion"] * params["links"][last]["length"]]))]
                break
            items.append(("site", pl, pp))
            if wrap != "none":
                items.append(("wrap", c["joint"], c["side"], c["lever"]))
            items.append(("site", cl, cp))
        else:
            items.append(("site", cl, cp - np.array(
                [0, 0, m["insertion"] * params["links"][last]["length"]])))
        out.append(items)
    return out


# --------------------------------------------------------------------------- the files
def _write(params: dict[str, Any], family: str, name: str, folder: Path) -> Path:
    if family == "viapoint":
        return _write_viapoint(params, name, folder)
    return _write_mjcf(params, name, folder)


def _muscle_file(params: dict[str, Any], name: str, folder: Path, model: dict[str, str],
                 paths: list[list[dict]] | None) -> Path:
    """The ``.muscles.yaml``: joints and their sampling ranges, each muscle's board, K and
    f_max, and either its via points (``paths``) or, naming an MJCF, nothing more (the
    tendon of its name is its path)."""
    muscles = []
    for i, m in enumerate(params["muscles"]):
        entry = {"name": m["name"], "board_id": i + 1, "K": m["K"], "f_max": m["f_max"]}
        if paths is not None:
            entry["path"] = paths[i]
        muscles.append(entry)
    description = {
        "robot": name, **model, "joint_encoders": True,
        "joints": [{"name": j["name"], "range": [-j["half_range"], j["half_range"]]}
                   for j in params["joints"]],
        "defaults": {"f_floor": F_FLOOR, **BOARD}, "muscles": muscles}
    out = folder / f"{name}.muscles.yaml"
    out.write_text(f"# {name}: drawn by pimbs_sim.population (seeded; do not edit)\n"
                   + yaml.safe_dump(description, sort_keys=False, default_flow_style=None))
    return out


def _write_viapoint(params: dict[str, Any], name: str, folder: Path) -> Path:
    urdf = folder / f"{name}.urdf"
    urdf.write_text(_urdf(name, params))
    paths = [[{"link": link, "point": _rounded(point)} for _, link, point in items]
             for items in _paths(params, ["none"] * params["dof"])]
    return _muscle_file(params, name, folder, {"urdf": urdf.name}, paths)


def _write_mjcf(params: dict[str, Any], name: str, folder: Path) -> Path:
    """The arm as an MJCF: bodies link1..linkN nested under the world, one hinge each; sites
    of the base in the world body; a wrapping geom per (joint, side, radius) used. The
    muscle file naming it gives the sampling ranges, K and f_max (an MJCF says neither)."""
    root = ET.Element("mujoco", model=name)
    ET.SubElement(root, "compiler", angle="radian", autolimits="true")
    ET.SubElement(root, "option", gravity="0 0 -9.81", timestep=f"{params['timestep']:g}")
    default = ET.SubElement(root, "default")
    ET.SubElement(default, "geom", contype="0", conaffinity="0")
    ET.SubElement(default, "site", size="0.004")
    world = ET.SubElement(root, "worldbody")
    bodies = {"base_link": world}
    parent = world
    for k, (joint, link) in enumerate(zip(params["joints"], params["links"], strict=True)):
        body = ET.SubElement(parent, "body", name=link["name"],
                             pos=_xyz(_joint_origin(params, k)))
        limit = joint["half_range"] + LIMIT_MARGIN
        ET.SubElement(body, "joint", name=joint["name"], type="hinge", axis=_xyz(joint["axis"]),
                      range=f"{-limit:g} {limit:g}", damping=f"{params['damping'][k]:.4g}",
                      armature=f"{params['armature'][k]:g}")
        ixx, izz = _rod_inertia(link)
        ET.SubElement(body, "inertial", pos=f"0 0 {-link['com']:g}", mass=f"{link['mass']:g}",
                      diaginertia=f"{ixx:.6g} {ixx:.6g} {izz:.6g}")
        ET.SubElement(body, "geom", type="capsule", size="0.01",
                      fromto=f"0 0 0 0 0 {-link['length']:g}", mass="0")
        bodies[link["name"]] = body
        parent = body
    tendon = ET.SubElement(root, "tendon")
    geoms: dict[tuple, str] = {}
    for m, items in zip(params["muscles"], _paths(params, params["wrap"]), strict=True):
        spatial = ET.SubElement(tendon, "spatial", name=m["name"], width="0.002")
        count = 0
        for item in items:
            if item[0] == "pulley":
                ET.SubElement(spatial, "pulley", divisor="2")
            elif item[0] == "site":
                site = f"{m['name']}_s{count}"
                count += 1
                ET.SubElement(bodies[item[1]], "site", name=site, pos=_xyz(item[2]))
                ET.SubElement(spatial, "site", site=site)
            else:
                geom, side_site = _wrap_geom(params, bodies, geoms, *item[1:])
                ET.SubElement(spatial, "geom", geom=geom, sidesite=side_site)
    ET.indent(root)
    xml = folder / f"{name}.xml"
    xml.write_text(f"<!-- {name}: drawn by pimbs_sim.population (seeded; do not edit) -->\n"
                   + ET.tostring(root, encoding="unicode") + "\n")
    return _muscle_file(params, name, folder, {"mjcf": xml.name}, None)


def _wrap_geom(params: dict[str, Any], bodies: dict[str, ET.Element], geoms: dict[tuple, str],
               k: int, side: int, radius: float) -> tuple[str, str]:
    """The wrapping geom (in the child body, at the joint) and the side site picking the
    side the tendon passes, made once per (joint, side, radius)."""
    key = (k, side, radius)
    if key not in geoms:
        kind = params["wrap"][k]
        child = bodies[_link(params, k)]
        geom = f"wrap_j{k + 1}_{len(geoms)}"
        attrs = {"name": geom, "type": kind, "mass": "0"}
        if kind == "cylinder":
            attrs.update(size=f"{radius:g} 0.01", zaxis=_xyz(params["joints"][k]["axis"]))
        else:
            attrs["size"] = f"{radius:g}"
        ET.SubElement(child, "geom", **attrs)
        u, _ = _frame(params["joints"][k]["axis"])
        ET.SubElement(child, "site", name=f"{geom}_side", pos=_xyz(side * 3 * radius * u))
        geoms[key] = geom
    return geoms[key], f"{geoms[key]}_side"


def _xyz(v: Iterable[float]) -> str:
    return " ".join(f"{x:.6g}" for x in np.asarray(list(v), float) + 0.0)


def _rounded(v: Iterable[float], digits: int = 6) -> list[float]:
    return [round(float(x), digits) + 0.0 for x in v]


# ---------------------------------------------------------------------------- the check
def _drivable(description: Path, samples: int, seed: int) -> tuple[str | None, dict[str, int]]:
    """None and the replaced counts per map when the arm is drivable, else why not."""
    try:
        arm = ArmModel.load(description)
    except DescriptionError as exc:
        return f"does not load ({exc})", {}
    problem = both_ways_problem(arm, routing_report(arm, check_poses(arm)))
    if problem:
        return f"one-sided: {problem}", {}
    replaced = {}
    for map_kind in ("al", "atl"):
        short = _precheck(arm, seed, map_kind)
        if short:
            return short, {}
        try:
            plan = plan_poses(arm, samples, seed, map_kind)
        except InfeasiblePoseError:
            return f"{map_kind}: a pose with no feasible draw", {}
        if len(plan.replaced) > MAX_REPLACED_SHARE * samples:
            return f"{map_kind}: {len(plan.replaced)} of {samples} poses replaced", {}
        replaced[map_kind] = len(plan.replaced)
    return None, replaced


def _precheck(arm: ArmModel, seed: int, map_kind: str) -> str | None:
    """The first ``PRECHECK_POSES`` of the plan's sequence, without replacements: a cheap
    refusal of an arm that would need many (each replacement may try 1000 draws)."""
    n = PRECHECK_POSES
    poses = sample_poses(arm.joint_range, n, np.random.default_rng([seed, 0]))
    if map_kind == "atl":
        low, high = atl_floor_range(arm)
        floors = np.maximum(np.random.default_rng([seed, 1]).uniform(low, high,
                                                                     (n, arm.n_muscles)),
                            F_FLOOR)
    else:
        floors = np.full((n, arm.n_muscles), F_FLOOR)
    bad = sum(not feasible(arm, p, f) for p, f in zip(poses, floors, strict=True))
    if bad > 2 * MAX_REPLACED_SHARE * n:
        return f"{map_kind}: {bad} of the first {n} poses cannot be held"
    return None


