"""What a robot description means, in words: joints, muscles, moment arms, the both-ways check.

The muscle file is a list of via points; what a user needs to see is what it implies (which
muscle turns which joint which way, how strongly, over the whole range, and where a joint
cannot be driven both ways), before any collection discovers a routing mistake the hard way.
"""

from __future__ import annotations

import os
import shutil
import sys
import textwrap

import numpy as np

from pimbs_arm.model import ArmModel
from pimbs_arm.routing import MIN_MOMENT_ARM, RoutingReport
from pimbs_calibration.urdf_model import UNLIMITED, link_masses, parse_joints

PIPED_WIDTH = 100  # columns when the output is not a terminal (a file, a pipe, a test)


def terminal_width() -> int:
    """Columns to fit the text in: the terminal's (or ``COLUMNS``), else ``PIPED_WIDTH``."""
    if "COLUMNS" in os.environ or sys.stdout.isatty():
        return max(40, shutil.get_terminal_size((PIPED_WIDTH, 24)).columns)
    return PIPED_WIDTH


def describe(arm: ArmModel, report: RoutingReport, max_poses: int = 5,
             width: int | None = None) -> list[str]:
    """Lines of text explaining the description and the routing check, none wider than
    ``width`` columns (default: the terminal's) where words allow: a model with 40 joints
    and 200 muscles is read in a terminal too."""
    width = terminal_width() if width is None else width
    robot = arm.robot
    mjcf = arm.backend.kind == "mjcf"
    source, kinds, locked_lines, routes = _mjcf_parts(arm) if mjcf else _urdf_parts(arm)
    what = "MJCF" if mjcf else "URDF"
    lines = [f"robot {robot.name}: {robot.muscle_path}", *source,
             f"  joint angles from {'joint encoders' if robot.joint_encoders else 'the model'}",
             "", f"driven joints ({arm.n_joints}, in column order):"]
    for name, rng, lim in zip(arm.joints, arm.joint_range, arm.joint_limits, strict=True):
        limits = ("none (continuous)" if lim[1] >= UNLIMITED
                  else f"[{lim[0]:.3g}, {lim[1]:.3g}]")
        lines.append(f"  {name:<22} {kinds[name]:<10} sampled in [{rng[0]:.3g}, "
                     f"{rng[1]:.3g}] rad, {what} limits {limits}")
    if locked_lines:
        what = ("locked and following joints ({}; not driven by muscles: held rigid, or moved "
                "by the joint they follow):" if any(" follows " in x for x in locked_lines)
                else "locked joints ({}; not driven by muscles, held rigid):")
        lines += ["", what.format(len(locked_lines)), *locked_lines]
    via = "MuJoCo tendon path" if mjcf else "via points"
    name = max(14, *(len(m) for m in arm.muscles))
    lines += ["", f"muscles ({arm.n_muscles}):",
              f"  {'name':<{name}} {'board':>5} {'f_floor':>8} {'f_max':>7} {'K':>7}  {via}"]
    for m, route in zip(robot.muscles, routes, strict=True):
        row = (f"  {m.name:<{name}} {m.board_id:>5} {m.f_floor:>8.4g} {m.f_max:>7.4g} "
               f"{m.K:>7.4g}  ")
        # a long path goes on below itself, broken between its steps only (and starts on a
        # line of its own where the columns before it leave no room for its longest step)
        longest = max(len(step) for step in route.split(" > ")) + 2
        steps = "\xa0> ".join(step.replace(" ", "\xa0") for step in route.split(" > "))
        indent = row if width - len(row) >= longest else "      "
        wrapped = textwrap.wrap(steps, width, initial_indent=indent,
                                subsequent_indent=" " * len(indent), break_long_words=False,
                                break_on_hyphens=False)
        lines += ([] if indent == row else [row.rstrip()]) + [
            part.replace("\xa0", " ") for part in wrapped]
    lines += ["", f"moment arms r = -dl/dtheta in mm over {len(report.poses)} poses (centre, "
              "corners, random); r > 0 turns the joint towards positive angles:",
              *moment_arm_table(arm, report, width)]
    lines += ["", *both_ways_lines(arm, report, max_poses)]
    return [part for line in lines for part in _fit(line, width)]


def moment_arm_table(arm: ArmModel, report: RoutingReport, width: int) -> list[str]:
    """Each muscle's moment-arm range (mm) about each joint it crosses, a row per muscle and
    a column per joint. Where the columns do not fit in ``width`` they are cut into blocks of
    joints, one under the other, and a block lists only the muscles that cross one of its
    joints (a finger's muscles in the finger's block, not 40 rows of '-')."""
    r = report.moment_arm * 1e3
    crosses = report.crosses()
    cells = [[f"{r[:, i, j].min():+.1f}..{r[:, i, j].max():+.1f}" if crosses[i, j] else "-"
              for j in range(arm.n_joints)] for i in range(arm.n_muscles)]
    name = max(14, *(len(m) for m in arm.muscles))
    column = [2 + max(12, len(joint), *(len(row[j]) for row in cells))
              for j, joint in enumerate(arm.joints)]
    blocks: list[list[int]] = [[]]
    for j in range(arm.n_joints):
        used = 2 + name + sum(column[k] for k in blocks[-1])
        if blocks[-1] and used + column[j] > width:
            blocks.append([])
        blocks[-1].append(j)
    lines = []
    for b, joints in enumerate(blocks):
        if len(blocks) > 1:
            which = (f"joint {joints[0] + 1}" if len(joints) == 1
                     else f"joints {joints[0] + 1}-{joints[-1] + 1}")
            lines += [""] * (b > 0) + [f"  {which} of {arm.n_joints}:"]
        lines.append("  " + " " * name + "".join(f"{arm.joints[j]:>{column[j]}}"
                                                  for j in joints))
        for i, muscle in enumerate(arm.muscles):
            if len(blocks) == 1 or crosses[i, joints].any():
                lines.append("  " + f"{muscle:<{name}}"
                             + "".join(f"{cells[i][j]:>{column[j]}}" for j in joints))
    return lines


def _fit(line: str, width: int) -> list[str]:
    """``line`` broken at spaces into lines of at most ``width`` columns, the rest indented
    under its start (a word longer than that, a file's path, stays whole)."""
    if len(line) <= width:
        return [line]
    indent = " " * (len(line) - len(line.lstrip()))
    return textwrap.wrap(line.lstrip(), width, initial_indent=indent,
                         subsequent_indent=indent + "    ", break_long_words=False,
                         break_on_hyphens=False) or [line]


def _urdf_parts(arm: ArmModel) -> tuple[list[str], dict[str, str], list[str], list[str]]:
    """URDF + via points: source lines, joint types, locked joints, each muscle's via points."""
    robot = arm.robot
    text = robot.urdf_path.read_text()
    urdf = parse_joints(robot.urdf_path, text)
    source = [f"  URDF {robot.urdf_path}",
              f"  total mass {sum(link_masses(text).values()):.4g} kg "
              f"({arm.backend.moving_mass():.4g} kg moved by the driven joints)"]
    locked = []
    for name, value in robot.locked:
        leader = urdf[name].mimic[0] if urdf[name].mimic else None
        how = ("" if leader is None else f" (mimic of {leader})" if leader in urdf
               else f" (mimic of {leader}, which is not a joint of the URDF)")
        locked.append(f"  {name:<22} {urdf[name].type:<10} at {value:.4g}{how}")
    for name, leader, m, c in robot.followers:
        locked.append(f"  {name:<22} follows driven {leader}: q = {m:g}*{leader} + {c:g}")
    routes = [f"{len(m.path)} on " + " > ".join(dict.fromkeys(v.link for v in m.path))
              for m in robot.muscles]
    return source, {j: urdf[j].type for j in arm.joints}, locked, routes


def _mjcf_parts(arm: ArmModel) -> tuple[list[str], dict[str, str], list[str], list[str]]:
    """MJCF: source lines (and the tendons that are not muscles), joint types, locked joints,
    each muscle's tendon path (sites, wrapping geoms, pulleys) as MuJoCo compiled it."""
    from pimbs_calibration.mjcf import read_mjcf

    robot = arm.robot
    mjcf = read_mjcf(robot.mjcf_path)
    total = float(arm.backend.mj_model.body_mass.sum())
    source = [f"  MJCF {robot.mjcf_path} (muscle lengths and moment arms from MuJoCo's "
              "tendons)",
              f"  total mass {total:.4g} kg ({arm.backend.moving_mass():.4g} kg moved by the "
              "driven joints)"]
    muscles = {m.name for m in robot.muscles}
    unused = [t.name for t in mjcf.tendons if t.spatial and t.name not in muscles]
    fixed = [t.name for t in mjcf.tendons if not t.spatial]
    if unused:
        source.append(f"  spatial tendons not used as muscles: {', '.join(unused)}")
    if fixed:
        source.append(f"  fixed tendons ignored (joint couplings, not muscles): "
                      f"{', '.join(fixed)}")
    inactive = [c.equality for c in mjcf.couplings if not c.active]
    if inactive:
        source.append(f"  joint equalities off in the model (active=\"false\"), not applied: "
                      f"{', '.join(inactive)}")
    if mjcf.other_equalities:
        source.append(f"  equality constraints that are not joint couplings, not applied to "
                      f"the muscles' geometry: {', '.join(mjcf.other_equalities)}")
    kinds = {j.name: j.type for j in mjcf.joints}
    coupled = {c.follower: c for c in mjcf.couplings if c.active}
    locked = []
    for name, value in robot.locked:
        how = "" if name not in coupled else (
            f" (by equality '{coupled[name].equality}')" if coupled[name].leader is None
            else f" (follows {coupled[name].leader}: equality '{coupled[name].equality}')")
        locked.append(f"  {name:<22} {kinds[name]:<10} at {value:.4g}{how}")
    for c in robot.couplings:
        locked.append(f"  {c.follower:<22} {kinds[c.follower]:<10} follows {c.leader}: "
                      f"{c.formula()} (equality '{c.equality}')")
    held = [j.name for j in mjcf.joints if j.type in ("ball", "free")]
    if held:
        locked.append(f"  {', '.join(held)}: ball/free, held at the model's qpos0")
    tendons = {t.name: t for t in mjcf.tendons}
    source.append(_limits_line(robot, tendons))
    routes = [" > ".join(tendons[m.name].route) for m in robot.muscles]
    return source, kinds, locked, routes


def _limits_line(robot, tendons) -> str:
    """Where the muscles' f_max came from: the tendons' actuators, the muscle file, or the
    default for a tendon nothing declares a force for (and the floor's rule)."""
    from pimbs_calibration.description import MJCF_MUSCLE_DEFAULTS, mjcf_default_floor

    counts = {"actuator": 0, "file": 0, "default": 0}
    for m in robot.muscles:
        declared = tendons[m.name].force_limit
        if declared is not None and m.f_max == declared:
            counts["actuator"] += 1
        elif declared is None and m.f_max == MJCF_MUSCLE_DEFAULTS["f_max"]:
            counts["default"] += 1
        else:
            counts["file"] += 1
    parts = [f"{what} for {n} muscle{'s' * (n != 1)}" for n, what in (
        (counts["actuator"], "its tendon's actuator"), (counts["file"], "the muscle file"),
        (counts["default"], f"the default {MJCF_MUSCLE_DEFAULTS['f_max']:g} N (no actuator "
                            "declares a force)")) if n]
    scaled = sum(m.f_floor == mjcf_default_floor(m.f_max) for m in robot.muscles)
    return (f"  limits: f_max from {', '.join(parts)}; f_floor = min(10 N, f_max/20) for "
            f"{scaled} of {len(robot.muscles)} (a muscle file may set either)")


def both_ways_lines(arm: ArmModel, report: RoutingReport, max_poses: int = 5) -> list[str]:
    """The check that every driven joint can be turned both ways at every checked pose."""
    bad = report.one_sided()
    n = len(report.poses)
    lines = [f"both-ways check (some muscle with r >= +{MIN_MOMENT_ARM * 1e3:g} mm and some "
             f"with r <= -{MIN_MOMENT_ARM * 1e3:g} mm, per joint and pose):"]
    for j, name in enumerate(arm.joints):
        where = np.flatnonzero(bad[:, j])
        if not len(where):
            lines.append(f"  {name:<22} ok at all {n} poses")
            continue
        lines.append(f"  {name:<22} FAILS at {len(where)} of {n} poses, e.g.:")
        for p in where[:max_poses]:
            pose = ", ".join(f"{a:.3f}" for a in report.poses[p])
            side = report.missing_side(p, j)
            towards = "either way" if side == "either" else f"towards {side} angles"
            lines.append(f"    theta=[{pose}]: nothing turns it {towards}")
    return lines
