"""The approach direction of a muscle, as static friction sees it.

A tendon sliding over its guides (capstan friction) loads the loadcell more when the motor
last pulled the wire in than when it last paid it out. Which one applies is decided by the
last *real* motion: servo jitter and sensor noise of a few micrometres do not reverse it.
This is the play (backlash) operator: the direction flips only once the length has moved
back from its extreme by more than a band. The recording's ``approach`` column and the
simulated boards' friction both use it, so they agree on what "approach" means.
"""

from __future__ import annotations

import numpy as np

BAND_M = 2e-4  # m of travel back that reverses the friction


class ApproachTracker:
    """Feed every length reading; ``direction`` is +1 lengthening, −1 shortening, 0 unknown."""

    def __init__(self, n_muscles: int, band: float = BAND_M) -> None:
        self.band = band
        self.direction = np.zeros(n_muscles, dtype=np.int8)
        self._extreme: np.ndarray | None = None  # furthest point in the current direction

    def update(self, length: np.ndarray) -> np.ndarray:
        x = np.asarray(length, dtype=float)
        if self._extreme is None:
            self._extreme = x.copy()
            return self.direction.copy()
        d, ext = self.direction, self._extreme
        ext = np.where(d > 0, np.maximum(ext, x), np.where(d < 0, np.minimum(ext, x), ext))
        moved = x - ext
        flip = np.where(d > 0, moved < -self.band,
                        np.where(d < 0, moved > self.band, np.abs(moved) > self.band))
        self.direction = np.where(flip, np.sign(moved), d).astype(np.int8)
        self._extreme = np.where(flip, x, ext)
        return self.direction.copy()
