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

BAND_M = 5e-4  # m of travel back that reverses the friction (stable with μ up to ~0.5)


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


class FrictionPlay:
    """Continuous friction state s ∈ [−1, 1] of each muscle (the simulated boards' view).

    A capstan sticks within its band: as the motor reverses, the loadcell tension moves
    continuously from ``f·e^{−μ}`` towards ``f·e^{+μ}`` over ``band`` metres of travel,
    rather than jumping. A jump would itself move the elastic element by more than the band
    and reverse the friction again: a limit cycle that no real tendon shows. Effects read
    ``s`` in place of the discrete approach direction.
    """

    def __init__(self, n_muscles: int, band: float = BAND_M) -> None:
        self.band = band
        self.state = np.zeros(n_muscles)
        self._last: np.ndarray | None = None

    def update(self, length: np.ndarray) -> np.ndarray:
        x = np.asarray(length, dtype=float)
        if self._last is not None:
            self.state = np.clip(self.state + (x - self._last) / self.band, -1.0, 1.0)
        self._last = x.copy()
        return self.state.copy()
