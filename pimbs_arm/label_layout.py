"""Place text labels next to points of a drawn figure so that no two of them collide.

Several wires of a real arm end at one place (six muscles of a shoulder, a flexor beside its
extensor), and labels written at their anchors pile into one unreadable blob. This pass
works in display pixels after the figure's layout is final: each label, in turn, takes the
nearest free spot on rings around its anchor — free of the labels already placed, of every
text already on the figure (titles, tick and axis labels, the legend) and of the other
anchors — and is joined to its anchor by a thin leader line when it had to move away. A
label with no free spot is left out rather than written over another text: where dozens of
wires end close together, the legend names them.
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
                 region: Bbox, max_radius_pt: float = RADII_PT[-1]) -> list[Bbox]:
    """Add each label, in order, to ``ax`` at a spot inside ``region`` and within
    ``max_radius_pt`` of its anchor that overlaps nothing placed so far nor any of
    ``obstacles``, or leave it out where there is none; returns the boxes used. Call after
    ``fig.canvas.draw()`` and keep the layout fixed afterwards (anchors are in display
    pixels)."""
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
        spot = _free_spot(label.anchor, w, h, px_per_pt, taken, region, max_radius_pt)
        if spot is None:
            continue
        box, dx, radius = spot
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


def _free_spot(anchor: tuple[float, float], w: float, h: float, px_per_pt: float,
               taken: Sequence[Bbox], region: Bbox, max_radius_pt: float
               ) -> tuple[Bbox, float, float] | None:
    """The nearest spot on the rings around ``anchor`` (out to ``max_radius_pt``) where a
    ``w`` x ``h`` box lies inside ``region`` and clear of ``taken``: (box, its x offset, the
    ring's radius in pt). All spots are tested at once (a model with 70 muscles has hundreds
    of texts to keep clear of)."""
    radius, angle = np.meshgrid([r for r in RADII_PT if r <= max_radius_pt],
                                np.radians(ANGLES_DEG), indexing="ij")
    radius, angle = radius.ravel(), angle.ravel()  # ring by ring, nearest first
    dx = radius * px_per_pt * np.cos(angle)
    x0 = anchor[0] + dx - np.where(dx >= -1e-9, 0.0, w)
    y0 = anchor[1] + radius * px_per_pt * np.sin(angle) - h / 2
    inside = ((x0 >= region.x0) & (x0 + w <= region.x1)
              & (y0 >= region.y0) & (y0 + h <= region.y1))
    if taken:
        other = np.array([b.extents for b in taken])  # (K, 4): x0, y0, x1, y1
        across = (np.minimum(x0[:, None] + w, other[:, 2]) > np.maximum(x0[:, None], other[:, 0]))
        up = (np.minimum(y0[:, None] + h, other[:, 3]) > np.maximum(y0[:, None], other[:, 1]))
        inside &= ~(across & up).any(axis=1)
    free = np.flatnonzero(inside)
    if not len(free):
        return None
    k = free[0]
    return Bbox.from_bounds(x0[k], y0[k], w, h), float(dx[k]), float(radius[k])
