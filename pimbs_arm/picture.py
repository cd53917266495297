"""A picture of the routing: the arm's bones and every muscle's wire path, in metres.

Everything drawn comes from the kinematics the arm's backend computes (``ArmModel.skeleton``
and ``ArmModel.wire_paths``: pinocchio for a URDF, MuJoCo for an MJCF), so a joint sits where
it turns and a wire runs where the model measures it: branches after a pulley apart, arcs over
wrapping surfaces. One panel per pose (the home pose and, if asked, another), framed on the
moving part of the arm with the same scale on every axis. A community model has 40 to 70
muscles: each gets its own colour and marker pair, the legend stands beside the panels (in
columns where needed), and a label is written at a wire's end only where it fits, placed
after the layout is final so it collides with no other text (``label_layout.py``).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pimbs_arm.backend import Skeleton, WirePath
from pimbs_arm.label_layout import RADII_PT, Label, figure_text_boxes, place_labels
from pimbs_arm.model import ArmModel
from pimbs_arm.routing import MIN_MOMENT_ARM

PANEL_IN = 7.5  # inches: width and height of one pose's panel
MARKERS = ("o", "s", "^", "D", "v", "P")  # with 20 colours: 120 muscles told apart
TITLE_LINES = 3  # the pose under a panel's title: at most this many lines of joint angles
LEGEND_COLUMNS = 2  # a legend with one entry per muscle at most this wide, else by joint


def plot_routing(arm: ArmModel, out: Path, poses: Sequence[tuple[str, np.ndarray]]) -> None:
    """Write a PNG with one 3-D panel per ``(title, theta)``."""
    import matplotlib.pyplot as plt

    fig = routing_figure(arm, poses)
    fig.savefig(out, dpi=110)
    plt.close(fig)


def routing_figure(arm: ArmModel, poses: Sequence[tuple[str, np.ndarray]]):
    """The figure of :func:`plot_routing`, labels placed, layout fixed (not yet saved)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    fontsize = 8.0 if arm.n_muscles <= 30 else 7.0
    styles, legend = _legend(arm, poses[0], fontsize)
    drawn = [(arm.skeleton(theta), arm.wire_paths(theta)) for _, theta in poses]
    lo, hi = _view_box(drawn)  # one box for every panel: poses compare at one scale
    view = _view(_drawn_points(drawn[:1]))
    ncol = legend_columns(len(legend.entries), fontsize, PANEL_IN)
    legend_in = ncol * (max(len(text) for _, text in legend.entries) * 0.55 * fontsize / 72
                        + 0.55)
    fig = plt.figure(figsize=(PANEL_IN * len(poses) + legend_in, PANEL_IN),
                     layout="constrained")
    anchors = []
    for k, ((title, theta), (skeleton, wires)) in enumerate(zip(poses, drawn, strict=True)):
        ax = fig.add_subplot(1, len(poses), k + 1, projection="3d")
        for bone in skeleton.bones:
            ax.plot(*np.stack(bone).T, color="0.35", lw=3, solid_capstyle="round", zorder=1)
        todo = []
        for p, joint_names in _joints_by_place(skeleton).items():
            ax.scatter(*p, s=50, color="black", depthshade=False, zorder=3)
            todo.append((np.array(p), " + ".join(joint_names), "0.2", 8.0, "normal"))
        for name, wire, (colour, marker) in zip(arm.muscles, wires, styles, strict=True):
            for branch in wire.branches:
                ax.plot(*branch.T, "-", color=colour, lw=1.6, zorder=2)
            ax.plot(*wire.attachments.T, marker, color=colour, ms=3, ls="none", zorder=2)
            todo.append((wire.end, name, colour, 8.5 if arm.n_muscles <= 30 else 7.5, "bold"))
        anchors.append((ax, todo))
        _frame(ax, lo, hi, view)
        ax.set_title(f"{arm.robot.name}: {title}\n" + pose_text(arm.joints, theta), fontsize=10)
    handles = [Line2D([], [], color=c, marker=mk, ms=4, lw=1.6) for (c, mk), _ in legend.entries]
    fig.legend(handles, [text for _, text in legend.entries], loc="outside right upper",
               ncols=ncol, fontsize=fontsize, title=legend.title, title_fontsize=fontsize + 1,
               handlelength=1.8, columnspacing=1.0, borderaxespad=0.5)
    _fill(fig, [ax for ax, _ in anchors], lo, hi)
    _tidy_axes(fig, [ax for ax, _ in anchors])
    _label(fig, anchors)
    return fig


@dataclass
class _Legend:
    title: str
    entries: list[tuple[tuple[object, str], str]]  # ((colour, marker), text)


def _legend(arm: ArmModel, pose: tuple[str, np.ndarray], fontsize: float
            ) -> tuple[list[tuple[object, str]], _Legend]:
    """Each muscle's (colour, marker) and the legend that explains them: one entry per muscle
    (with its board) while that fits in a few columns beside the panels; beyond that (a
    trunk of 200 muscles) one entry per driven joint, the muscles coloured by the joint they
    turn most at ``pose`` (title, theta), their names left to the labels."""
    names = [f"{m.name} (board {m.board_id})" for m in arm.robot.muscles]
    if legend_columns(len(names), fontsize, PANEL_IN) <= LEGEND_COLUMNS:
        styles = muscle_styles(arm.n_muscles)
        return styles, _Legend("muscles", list(zip(styles, names, strict=True)))
    lever = np.abs(arm.muscle_jacobian(pose[1]))  # (M, N)
    crossed = lever.max(axis=1) >= MIN_MOMENT_ARM
    group = [arm.joints[j] if c else "no driven joint"
             for j, c in zip(lever.argmax(axis=1), crossed, strict=True)]
    order = list(dict.fromkeys(j for j in (*arm.joints, "no driven joint") if j in group))
    look = dict(zip(order, muscle_styles(len(order)), strict=True))
    entries = [(look[j], f"{j} ({group.count(j)})") for j in order]
    return [look[j] for j in group], _Legend(
        f"{arm.n_muscles} muscles, by the joint\neach turns most ({pose[0]})", entries)


def muscle_styles(n: int) -> list[tuple[object, str]]:
    """(colour, marker) per muscle, no two alike: ten colours, then twenty, then twenty
    colours with one marker per round of them."""
    import matplotlib.pyplot as plt

    colours = plt.get_cmap("tab10" if n <= 10 else "tab20")
    return [(colours(i % colours.N), MARKERS[(i // colours.N) % len(MARKERS)])
            for i in range(n)]


def legend_columns(n: int, fontsize: float, height_in: float) -> int:
    """Columns the legend needs to fit ``n`` entries (and its title) in a figure's height."""
    rows = int((height_in * 72 - 4 * fontsize) // (1.75 * fontsize))
    return max(1, math.ceil(n / rows))


def pose_text(joints: Sequence[str], theta: np.ndarray, width: int = 95) -> str:
    """The pose in words, a few lines at most: the joints away from 0 by name (a model with
    dozens of joints holds most of them at 0)."""
    moved = [f"{j}={t:.2f}" for j, t in zip(joints, theta, strict=True) if abs(t) >= 5e-3]
    if not moved:
        return f"all {len(joints)} driven joints at 0 rad" if len(joints) > 1 else "at 0 rad"
    rest = len(joints) - len(moved)
    text = ", ".join(moved) + " rad" + (f"; the other {rest} at 0" if rest else "")
    lines = textwrap.wrap(text, width)
    if len(lines) > TITLE_LINES:
        shown = textwrap.wrap(text, width - 20)[:TITLE_LINES]
        left = len(moved) - sum(line.count("=") for line in shown)
        lines = shown[:-1] + [f"{shown[-1]} ... ({left} more)"]
    return "\n".join(lines)


def _joints_by_place(skeleton: Skeleton) -> dict[tuple, list[str]]:
    """Driven joints at one place (a two-axis shoulder, a knuckle) share a dot and a label."""
    at: dict[tuple, list[str]] = {}
    for name, p in skeleton.joints.items():
        at.setdefault(tuple(np.round(p, 4)), []).append(name)
    return at


def _drawn_points(drawn: Sequence[tuple[Skeleton, Sequence[WirePath]]]) -> np.ndarray:
    """(k, 3) every point the panels draw: the wires, the driven joints, the moving bones."""
    return np.vstack([p for skeleton, wires in drawn
                      for p in (skeleton.focus, *skeleton.joints.values(),
                                *(b for w in wires for b in w.branches))])


def _view_box(drawn: Sequence[tuple[Skeleton, Sequence[WirePath]]]
              ) -> tuple[np.ndarray, np.ndarray]:
    """Corners of the box the panels show: what they draw at every pose, a margin around it,
    no side thinner than a quarter of the longest (a planar arm)."""
    points = _drawn_points(drawn)
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = (lo + hi) / 2
    half = np.maximum((hi - lo) / 2, max((hi - lo).max() / 8, 0.025)) * 1.06
    return centre - half, centre + half


def _view(points: np.ndarray) -> tuple[float, float]:
    """(elevation, azimuth) in degrees: from a little above, looking across the direction in
    which the arm spreads least horizontally (so two legs stand side by side, a hand shows
    its length), turned 30 degrees for depth; from the front half (y < 0) where either
    way would do."""
    flat = points[:, :2] - points[:, :2].mean(axis=0)
    _, vectors = np.linalg.eigh(flat.T @ flat)
    across = vectors[:, 0]  # least spread: look along it
    base = np.degrees(np.arctan2(across[1], across[0]))
    base = base - 180 if base >= 0 else base  # the camera on the -y side
    return 18.0, base + 30


def _fill(fig, axes, lo: np.ndarray, hi: np.ndarray, share: float = 0.8) -> None:
    """Zoom each panel until the box spans ``share`` of it across or up, whichever comes
    first: matplotlib fits any box as if it were a cube seen from any side, so a long, thin
    arm (a forearm and hand) would otherwise fill a fraction of its panel."""
    from mpl_toolkits.mplot3d import proj3d

    fig.canvas.draw()
    corners = np.array(np.meshgrid(*np.stack([lo, hi], axis=1), indexing="ij"))
    corners = corners.reshape(3, -1)
    for ax in axes:
        x, y, _ = proj3d.proj_transform(*corners, ax.get_proj())
        px = ax.transData.transform(np.stack([x, y], axis=1))
        panel = ax.get_position().transformed(fig.transFigure)
        centre = np.array([(panel.x0 + panel.x1) / 2, (panel.y0 + panel.y1) / 2])
        reach = np.abs(px - centre).max(axis=0)
        zoom = share * min(panel.width / 2 / reach[0], panel.height / 2 / reach[1])
        ax.set_box_aspect(tuple(hi - lo), zoom=zoom)


def _tidy_axes(fig, axes, step: float = 4.0, tries: int = 8) -> None:
    """Keep the three axes' texts apart: where tick labels of two axes meet (at the box's
    corner) the axis with more ticks drops its own there, and each axis label moves out until
    it clears its own tick labels (matplotlib sets them a fixed distance apart, which a tall,
    thin box brings together). Leaves the figure drawn as it now is."""
    from matplotlib.ticker import FixedLocator

    for attempt in range(tries + 1):
        fig.canvas.draw()
        if attempt == tries:
            return
        renderer = fig.canvas.get_renderer()
        changed = False
        for ax in axes:
            ticks = {axis: _tick_boxes(axis, renderer) for axis in (ax.xaxis, ax.yaxis, ax.zaxis)}
            clash = {axis: [v for v, box in boxes if _touches(box, [
                b for other, more in ticks.items() if other is not axis for _, b in more])]
                for axis, boxes in ticks.items()}
            # of two axes whose tick labels meet, the one with more ticks gives one up
            thinned = [axis for axis in ticks if clash[axis] and len(ticks[axis]) > 2]
            if thinned:
                axis = max(thinned, key=lambda a: len(ticks[a]))
                axis.set_major_locator(FixedLocator([v for v, _ in ticks[axis]
                                                     if v not in clash[axis]]))
                changed = True
            for axis, boxes in ticks.items():
                if _touches(axis.label.get_window_extent(renderer), [b for _, b in boxes]):
                    axis.labelpad += step
                    changed = True
        if not changed:
            return


def _tick_boxes(axis, renderer) -> list[tuple[float, object]]:
    """(value, box) of each tick label ``axis`` shows."""
    lo, hi = sorted(axis.get_view_interval())
    return [(t.get_loc(), t.label1.get_window_extent(renderer)) for t in axis.get_major_ticks()
            if t.label1.get_visible() and t.label1.get_text() and lo <= t.get_loc() <= hi]


def _touches(box, others) -> bool:
    """Whether ``box`` overlaps any of ``others`` (display pixels)."""
    return any(min(box.x1, o.x1) > max(box.x0, o.x0) and min(box.y1, o.y1) > max(box.y0, o.y0)
               for o in others)


def _frame(ax, lo: np.ndarray, hi: np.ndarray, view: tuple[float, float]) -> None:
    """The box as the axes' limits, drawn to scale (the same metres per pixel on x, y and z,
    so lengths and moment arms look as they are), seen from ``view``."""
    from matplotlib.ticker import MaxNLocator

    extent = hi - lo
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(extent))
    for axis, side in zip((ax.xaxis, ax.yaxis, ax.zaxis), extent, strict=True):
        # ticks as dense on a short side as on the longest, so their labels stay apart
        axis.set_major_locator(MaxNLocator(max(2, round(6 * side / extent.max()))))
    ax.set_xlabel("x [m]", labelpad=10)
    ax.set_ylabel("y [m]", labelpad=10)
    ax.set_zlabel("z [m]", labelpad=10)
    ax.view_init(*view)


def _label(fig, anchors) -> None:
    """Place every panel's labels on the figure as last drawn, in its final layout, then
    freeze the layout: the anchors are display positions of the projected 3-D points."""
    from mpl_toolkits.mplot3d import proj3d

    renderer = fig.canvas.get_renderer()
    obstacles = figure_text_boxes(fig, renderer)
    for ax, todo in anchors:
        labels = []
        for p, text, colour, size, weight in todo:
            x, y, _ = proj3d.proj_transform(*p, ax.get_proj())
            labels.append(Label(tuple(ax.transData.transform((x, y))), text, colour, size,
                                weight))
        # where wires crowd, a label far from its wire end would only add a leader line
        reach = RADII_PT[-1] if len(labels) <= 20 else 40
        place_labels(fig, ax, labels, obstacles, ax.get_window_extent(renderer), reach)
    fig.set_layout_engine("none")
