"""Held poses in a continuous log: the collection's settle criterion applied after the fact.

Topics come at different rates; everything is brought onto the times of the muscle readings
(joint angles and temperatures interpolated linearly between their own samples; only the
span every required topic covers is used). A reading is *quiet* when, over the trailing
``window``, the mean of the second half differs from the first half's by less than the
tolerance for every length, tension and joint angle (``pimbs collect``'s test, without the
commands a log does not have). A held pose is a quiet stretch lasting ``min_hold``; quiet
stretches interrupted by a blip (noise, a bump) are joined when their means agree within the
tolerances, so one pose gives one row. Ramps between poses are never quiet and are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pimbs_import.bagread import LogError, Series
from pimbs_import.mapping import SettleRule
from pimbs_recording.approach import ApproachTracker


@dataclass
class Aligned:
    """All quantities at the base times (ns)."""

    time: np.ndarray  # (T,)
    theta: np.ndarray  # (T, N)
    length: np.ndarray  # (T, M)
    tension: np.ndarray  # (T, M)
    temperature: np.ndarray | None  # (T, M)


@dataclass
class HeldPose:
    start: int  # first and last index (inclusive) of the held stretch in ``Aligned``
    stop: int
    approach: np.ndarray  # (M,) int8


def align(series: dict[str, Series], log: str) -> Aligned:
    """Every quantity at the tension readings' times, inside the span all of them cover.

    Each element is interpolated from the messages that carry it (NaN elsewhere), so topics
    split over several publishers align too.
    """
    base = series["tension"]
    spans = [_finite_span(s) for s in series.values()]
    lo, hi = max(a for a, _ in spans), min(b for _, b in spans)
    keep = (base.time >= lo) & (base.time <= hi) & np.isfinite(base.values).any(axis=1)
    if keep.sum() < 2:
        raise LogError(f"{log}: the topics do not overlap in time (each covers a different "
                       "part of the log), so no reading has all quantities; check the "
                       "clocks ('clock: log' in --map uses the recorder's time for all)")
    t = base.time[keep]

    def at(q: str) -> np.ndarray | None:
        s = series.get(q)
        if s is None:
            return None
        if (s is base or np.array_equal(s.time, base.time)) and np.isfinite(s.values).all():
            return s.values[keep]
        columns = []
        for k in range(s.values.shape[1]):
            ok = np.isfinite(s.values[:, k])
            columns.append(np.interp((t - lo).astype(np.float64),
                                     (s.time[ok] - lo).astype(np.float64), s.values[ok, k]))
        return np.stack(columns, axis=1)

    return Aligned(time=t, theta=at("theta"), length=at("length"), tension=at("tension"),
                   temperature=at("temperature"))


def _finite_span(s: Series) -> tuple[int, int]:
    """First and last time at which every element has been seen."""
    ok = np.isfinite(s.values)
    firsts = [s.time[np.argmax(ok[:, k])] for k in range(ok.shape[1])]
    lasts = [s.time[len(ok) - 1 - np.argmax(ok[::-1, k])] for k in range(ok.shape[1])]
    return max(firsts), min(lasts)


def quiet(a: Aligned, rule: SettleRule) -> np.ndarray:
    """(T,) bool: the trailing window ending at each reading is at rest."""
    t = (a.time - a.time[0]) * 1e-9
    # the window reaches back to the last reading at or before its start (as the detector's)
    start = np.maximum(np.searchsorted(t, t - rule.window, side="right") - 1, 0)
    end = np.arange(len(t)) + 1
    count = end - start
    mid = start + count // 2
    ok = (count >= max(int(rule.min_readings), 2)) & (t - t[start] >= rule.window)
    for values, tol in ((a.theta, rule.theta_tol), (a.length, rule.length_tol),
                        (a.tension, rule.tension_tol)):
        c = np.vstack([np.zeros(values.shape[1]), np.cumsum(values - values[0], axis=0)])
        first = (c[mid] - c[start]) / np.maximum(mid - start, 1)[:, None]
        second = (c[end] - c[mid]) / np.maximum(end - mid, 1)[:, None]
        ok &= (np.abs(second - first) < tol).all(axis=1)
    return ok


def held_poses(a: Aligned, rule: SettleRule) -> list[HeldPose]:
    """The held stretches, in time order, with the approach direction into each."""
    q = quiet(a, rule)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], q.astype(np.int8), [0]])))
    runs = [[int(s), int(e) - 1] for s, e in zip(edges[::2], edges[1::2], strict=True)]
    merged: list[list[int]] = []
    for run in runs:
        if merged and _same_pose(a, merged[-1], run, rule):
            merged[-1][1] = run[1]
        else:
            merged.append(run)
    t = a.time * 1e-9
    # the quiet flag of the first reading covers the window before it: the hold began then
    held = [r for r in merged if t[r[1]] - t[r[0]] + rule.window >= rule.min_hold]
    # a motion is seen only once it has moved by a tolerance, up to a window after it began:
    # the last window of a stretch is not part of the held pose
    for r in held:
        r[1] = max(r[0], int(np.searchsorted(t, t[r[1]] - rule.window, side="right")) - 1)
    return _with_approach(a, held)


def _same_pose(a: Aligned, r1: list[int], r2: list[int], rule: SettleRule) -> bool:
    """Two quiet stretches are one held pose when their means agree (a blip between)."""
    for values, tol in ((a.theta, rule.theta_tol), (a.length, rule.length_tol),
                        (a.tension, rule.tension_tol)):
        m1 = values[r1[0]:r1[1] + 1].mean(axis=0)
        m2 = values[r2[0]:r2[1] + 1].mean(axis=0)
        if (np.abs(m1 - m2) >= tol).any():
            return False
    return True


def _with_approach(a: Aligned, runs: list[list[int]]) -> list[HeldPose]:
    """The play operator of ``pimbs collect`` over the lengths up to each held pose.

    Between two holds only the turning points matter to the operator, so the motion is
    thinned to its running extremes: fast on hour-long logs, the same directions.
    """
    tracker = ApproachTracker(a.length.shape[1])
    out, done = [], 0
    for start, stop in runs:
        motion = a.length[done:start + 1]
        if len(motion):
            for x in _turning_points(motion):
                tracker.update(x)
        out.append(HeldPose(start=start, stop=stop, approach=tracker.direction.copy()))
        done = stop + 1
    return out


def _turning_points(x: np.ndarray) -> np.ndarray:
    """Rows of ``x`` where some muscle's length changes direction (or stops or starts: a
    plateau's ends), plus the first and last rows."""
    if len(x) < 3:
        return x
    d = np.sign(np.diff(x, axis=0))
    turn = (d[1:] != d[:-1]).any(axis=1)
    return x[np.concatenate([[0], np.flatnonzero(turn) + 1, [len(x) - 1]])]
