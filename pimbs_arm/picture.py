"""A picture of the routing: the arm's links and every muscle's wire path, in metres.

The skeleton is drawn from the URDF tree (a line from each parent link's frame to its child's,
locked joints included, driven joints marked), the wires through their via points, one colour
and one label per muscle. One panel per pose: the home pose and, if asked, another.
Labels are placed after the layout is final, each where it collides with no other text
(``label_layout.py``), since several wires of a real arm end at one place.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pimbs_arm.label_layout import Label, figure_text_boxes, place_labels
from pimbs_arm.model import ArmModel
from pimbs_calibration.urdf_model import link_centres, parse_joints


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

    skeleton = _mjcf_skeleton(arm) if arm.backend.kind == "mjcf" else _urdf_skeleton(arm)
    edges, joint_link, centres = skeleton
    parents = {parent for parent, _ in edges}
    fig = plt.figure(figsize=(7.5 * len(poses), 7.5), layout="constrained")
    colours = plt.get_cmap("tab10" if arm.n_muscles <= 10 else "tab20")
    anchors: list[tuple[object, list[tuple[np.ndarray, str, object, float, str]]]] = []
    for k, (title, theta) in enumerate(poses):
        ax = fig.add_subplot(1, len(poses), k + 1, projection="3d")
        frames = arm.link_frames(theta)
        origins = {name: p for name, (_, p) in frames.items()}
        points = arm.via_points(theta)
        bones = [(origins[parent], origins[child]) for parent, child in edges
                 if parent in origins and child in origins]
        # a link with no child ends at twice its centre of mass (a forearm, a hand)
        bones += [(p, p + 2 * rot @ centres[name]) for name, (rot, p) in frames.items()
                  if name not in parents and name in centres]
        everything = np.vstack([*origins.values(), *points, *(b for _, b in bones)])
        for a, b in bones:
            ax.plot(*np.stack([a, b]).T, color="0.35", lw=3, solid_capstyle="round",
                    zorder=1)
        at: dict[tuple, list[str]] = {}  # joints at one place (a 2-axis shoulder) share a label
        for name in arm.joints:
            at.setdefault(tuple(np.round(origins[joint_link[name]], 4)), []).append(name)
        todo = []
        for p, names in at.items():
            ax.scatter(*p, s=60, color="black", depthshade=False, zorder=3)
            todo.append((np.array(p), " + ".join(names), "0.2", 8.0, "normal"))
        for i, (muscle, p) in enumerate(zip(arm.robot.muscles, points, strict=True)):
            colour = colours(i % colours.N)
            ax.plot(*p.T, "-o", color=colour, lw=1.8, ms=3,
                    label=f"{muscle.name} (board {muscle.board_id})", zorder=2)
            todo.append((p[-1], muscle.name, colour, 9.0, "bold"))
        anchors.append((ax, todo))
        _equal_axes(ax, everything)
        ax.set_xlabel("x [m]", labelpad=10)
        ax.set_ylabel("y [m]", labelpad=10)
        ax.set_zlabel("z [m]", labelpad=10)
        pose = ", ".join(f"{j}={t:.2f}" for j, t in zip(arm.joints, theta, strict=True))
        ax.set_title(f"{arm.robot.name}: {title}\n{pose} rad", fontsize=10)
        ax.view_init(elev=15, azim=-60)
        if k == 0:
            ax.legend(loc="upper left", fontsize=8, title="muscles", title_fontsize=9)
    _label(fig, anchors)
    return fig


def _label(fig, anchors) -> None:
    """Place every panel's labels once the layout is final, then freeze the layout: the
    anchors are display positions of the projected 3-D points."""
    from mpl_toolkits.mplot3d import proj3d

    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    obstacles = figure_text_boxes(fig, renderer)
    for ax, todo in anchors:
        labels = []
        for p, text, colour, size, weight in todo:
            x, y, _ = proj3d.proj_transform(*p, ax.get_proj())
            labels.append(Label(tuple(ax.transData.transform((x, y))), text, colour, size,
                                weight))
        place_labels(fig, ax, labels, obstacles, ax.get_window_extent(renderer))
    fig.set_layout_engine("none")


Skeleton = tuple[list[tuple[str, str]], dict[str, str], dict[str, np.ndarray]]


def _urdf_skeleton(arm: ArmModel) -> Skeleton:
    """(parent, child) link pairs, each driven joint's child link, link centres of mass."""
    text = arm.robot.urdf_path.read_text()
    urdf = parse_joints(arm.robot.urdf_path, text)
    return ([(j.parent, j.child) for j in urdf.values()],
            {name: urdf[name].child for name in arm.joints}, link_centres(text))


def _mjcf_skeleton(arm: ArmModel) -> Skeleton:
    """The same for an MJCF: its body tree, the body each driven joint moves, body centres."""
    from pimbs_calibration.mjcf import joint_names

    backend = arm.backend
    model = backend.mj_model
    names = joint_names(model)
    bodies = {b: model.body(b).name or f"body{b}" for b in range(model.nbody)}
    joint_link = {j: bodies[int(model.jnt_bodyid[names.index(j)])] for j in arm.joints}
    centres = {bodies[b]: np.array(model.body_ipos[b]) for b in range(1, model.nbody)}
    edges = [(parent, child) for child, parent in backend.body_parents().items()]
    return edges, joint_link, centres


def _equal_axes(ax, points: np.ndarray) -> None:
    """Same scale on x, y and z, so lengths and moment arms look as they are."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre, half = (lo + hi) / 2, max((hi - lo).max() / 2, 0.05) * 1.05
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))
