"""Which texts of a matplotlib figure overlap, as drawn.

Independent of how the project places its labels: the figure is drawn once with
``Text.draw`` wrapped, so exactly the texts that reach the canvas (titles, axis and tick
labels, legend entries, annotations, 3-D labels at their projected place) are collected
with their window extents, and every pair whose boxes intersect is reported.
"""

from __future__ import annotations

from contextlib import contextmanager

from matplotlib.backend_bases import FigureCanvasBase
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.text import Text
from matplotlib.transforms import Bbox


@contextmanager
def _recording_text_draws(found: list[tuple[str, Bbox]]):
    original = Text.draw

    def draw(self, renderer):
        original(self, renderer)
        if self.get_visible() and self.get_text().strip():
            # the text's own box: an annotation's extent would include its leader line
            found.append((self.get_text(), Text.get_window_extent(self, renderer).frozen()))

    Text.draw = draw
    try:
        yield
    finally:
        Text.draw = original


def drawn_texts(fig) -> list[tuple[str, Bbox]]:
    """(text, box in display pixels) of every non-empty text drawn on ``fig``."""
    found: list[tuple[str, Bbox]] = []
    if type(fig.canvas) is FigureCanvasBase:  # a bare Figure(): its canvas draws nothing
        FigureCanvasAgg(fig)
    with _recording_text_draws(found):
        fig.canvas.draw()
    return found


def overlapping_texts(fig, tolerance_px: float = 0.5) -> list[tuple[str, str]]:
    """Pairs of drawn texts whose boxes overlap by more than ``tolerance_px`` each way."""
    texts = drawn_texts(fig)
    pairs = []
    for i, (a, box_a) in enumerate(texts):
        for b, box_b in texts[i + 1:]:
            w = min(box_a.x1, box_b.x1) - max(box_a.x0, box_b.x0)
            h = min(box_a.y1, box_b.y1) - max(box_a.y0, box_b.y0)
            if w > tolerance_px and h > tolerance_px:
                pairs.append((a, b))
    return pairs


def texts_cut_off(fig, tolerance_px: float = 1.0) -> list[str]:
    """Drawn texts that stick out of the figure (cut off in the PNG)."""
    width, height = fig.canvas.get_width_height()
    return [text for text, box in drawn_texts(fig)
            if box.x0 < -tolerance_px or box.y0 < -tolerance_px
            or box.x1 > width + tolerance_px or box.y1 > height + tolerance_px]
