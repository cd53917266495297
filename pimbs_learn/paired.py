"""Paired comparison of two methods trained on the same samples with the same seeds.

Errors of body schemas trained on different draws of N samples spread over an order of
magnitude, so a difference of means says little; the change *within* each draw does. The
change is summarised on the log scale (L_eval is a squared error, positive, multiplicative
across draws): mean log ratio with a Student-t 95 % interval, reported as a ratio and as a
percentage change of L_eval.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats


@dataclass(frozen=True)
class PairedChange:
    """other / base over paired runs: geometric-mean ratio and its 95 % interval."""

    n: int
    ratio: float  # exp(mean log(other/base))
    low: float  # 95 % interval of that ratio
    high: float
    mean_ratio: float  # mean(other) / mean(base): the change of the mean L_eval

    @property
    def percent(self) -> float:
        return 100.0 * (self.ratio - 1.0)

    @property
    def significant(self) -> bool:
        """The interval excludes 'no change'."""
        return self.high < 1.0 or self.low > 1.0

    def text(self) -> str:
        return (f"{self.percent:+.0f} % [{100 * (self.low - 1):+.0f}, "
                f"{100 * (self.high - 1):+.0f}]")


def paired_change(base: np.ndarray, other: np.ndarray, level: float = 0.95) -> PairedChange:
    """Paired change of ``other`` against ``base`` (same length, same draws, positive)."""
    b, o = np.asarray(base, float), np.asarray(other, float)
    if b.shape != o.shape or b.ndim != 1 or len(b) < 2:
        raise ValueError("paired_change needs two 1-D arrays of the same length ≥ 2")
    d = np.log(np.maximum(o, 1e-300)) - np.log(np.maximum(b, 1e-300))
    mean = float(d.mean())
    half = float(stats.t.ppf(0.5 + level / 2, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d)))
    return PairedChange(len(d), float(np.exp(mean)), float(np.exp(mean - half)),
                        float(np.exp(mean + half)), float(o.mean() / b.mean()))
