"""Place text labels next to points of a drawn figure so that no two of them collide.

Several wires of a real arm end at one place (six muscles of a shoulder, a flexor beside its
extensor), and labels written at their anchors pile into one unreadable blob. This pass
works in display pixels after the figure's layout is final: each label, in turn, takes the
nearest free spot on rings around its anchor — free of the labels already placed, of every
text already on the figure (titles, tick and axis labels, the legend) and of the other
anchors — and is joined to its anchor by a thin leader line when it had to move away.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.text import Text
from matplotlib.transforms import Bbox

RADII_PT = (6, 12, 18, 24, 34, 46, 60, 76, 95, 118, 145)
ANGLES_DEG = (0, 25, -25, 50, -50, 75, -75, 180, 155, -155, 130, -130, 105, -105, 90, -90)
GAP_PX = 2.0  # clearance kept around every box


@dataclass(frozen=True)
class Label:
    """One label: where it points (display pixels), what it says and how it looks."""

    anchor: tuple[float, float]
    text: str
    colour: object = "0.2"
    fontsize: float = 8.0
    weight: str = "normal"


def figure_text_boxes(fig, renderer) -> list[Bbox]:
    """Boxes of the texts and legends already on ``fig`` (after a draw), to keep clear of."""
    boxes = []
    for text in fig.findobj(Text):
        if text.get_visible() and text.get_text().strip():
            boxes.append(text.get_window_extent(renderer))
    for ax in fig.axes:
        legend = ax.get_legend()
        if legend is not None:
            boxes.append(legend.get_window_extent(renderer))
    boxes += [lg.get_window_extent(renderer) for lg in fig.legends]
    return boxes


def place_labels(fig, ax, labels: Sequence[Label], obstacles: Sequence[Bbox],
                 region: Bbox) -> list[Bbox]:
    """Add each label to ``ax`` at a spot inside ``region`` that overlaps nothing placed so
    far nor any of ``obstacles``; returns the boxes used. Call after ``fig.canvas.draw()``
    and keep the layout fixed afterwards (anchors are in display pixels)."""
    renderer = fig.canvas.get_renderer()
    px_per_pt = fig.dpi / 72.0
    taken = [b.padded(GAP_PX) for b in obstacles]
    taken += [Bbox.from_bounds(x - 5, y - 5, 10, 10) for x, y in (lb.anchor for lb in labels)]
    used = []
    for label in labels:
        probe = Text(0, 0, label.text, fontsize=label.fontsize, fontweight=label.weight)
        probe.set_figure(fig)
        extent = probe.get_window_extent(renderer)
        w, h = extent.width, extent.height
        best = None
        for radius in RADII_PT:
            for angle in ANGLES_DEG:
                dx = radius * px_per_pt * np.cos(np.radians(angle))
                dy = radius * px_per_pt * np.sin(np.radians(angle))
                x, y = label.anchor[0] + dx, label.anchor[1] + dy
                left = x if dx >= -1e-9 else x - w
                box = Bbox.from_bounds(left, y - h / 2, w, h)
                cost = _overlap(box, taken) + 10 * _outside(box, region)
                if best is None or cost < best[0]:
                    best = (cost, box, dx, radius)
                if cost == 0:
                    break
            if best[0] == 0:
                break
        _, box, dx, radius = best
        to_fig = fig.transFigure.inverted()
        xy = to_fig.transform(label.anchor)
        text_xy = to_fig.transform((box.x0 if dx >= -1e-9 else box.x1, (box.y0 + box.y1) / 2))
        arrow = None if radius <= RADII_PT[1] else dict(
            arrowstyle="-", color=label.colour, lw=0.6, shrinkA=0, shrinkB=1, alpha=0.8)
        ax.annotate(label.text, xy=xy, xycoords="figure fraction", xytext=text_xy,
                    textcoords="figure fraction", ha="left" if dx >= -1e-9 else "right",
                    va="center", fontsize=label.fontsize, fontweight=label.weight,
                    color=label.colour, arrowprops=arrow, annotation_clip=False, zorder=5,
                    # a light backing keeps a label legible where it lies across a wire
                    bbox=dict(boxstyle="square,pad=0.05", fc="white", ec="none", alpha=0.75))
        taken.append(box.padded(GAP_PX))
        used.append(box)
    return used


def _overlap(box: Bbox, others: Sequence[Bbox]) -> float:
    """Total area (px²) of ``box`` covered by ``others``."""
    total = 0.0
    for o in others:
        w = min(box.x1, o.x1) - max(box.x0, o.x0)
        h = min(box.y1, o.y1) - max(box.y0, o.y0)
        if w > 0 and h > 0:
            total += w * h
    return total


def _outside(box: Bbox, region: Bbox) -> float:
    """Area (px²) of ``box`` that lies outside ``region``."""
    w = min(box.x1, region.x1) - max(box.x0, region.x0)
    h = min(box.y1, region.y1) - max(box.y0, region.y0)
    return box.width * box.height - max(w, 0) * max(h, 0)
