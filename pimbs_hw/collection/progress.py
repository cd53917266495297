"""What the person at the arm sees: a live progress panel, warnings, and the final summary.

The panel answers the questions asked while standing next to a 500-sample run: how far, how
fast, when done, is any muscle near its tension ceiling or getting hot, did anything go wrong.
"""

from __future__ import annotations

import time
from typing import Any

from rich.console import Console, Group
from rich.live import Live
from rich.progress_bar import ProgressBar
from rich.table import Table
from rich.text import Text

from pimbs_hw.collection.routine import Summary
from pimbs_hw.collection.temperature import hottest

WARN_C = 55.0  # °C shown in red: the driver starts derating tension ceilings at 60 °C


def _duration(seconds: float | None) -> str:
    if seconds is None:
        return "–"
    seconds = int(round(seconds))
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class LiveReporter:
    """Rich live panel (refreshed per sample); warnings scroll above it."""

    def __init__(self, console: Console | None = None, title: str = "pimbs collect") -> None:
        self.console = console or Console(stderr=True)
        self.title = title
        self._last: dict[str, Any] | None = None
        self._summary: Summary | None = None
        self._live = Live(Text(""), console=self.console, refresh_per_second=4,
                          transient=False)

    def __enter__(self) -> LiveReporter:
        self._live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self._live.__exit__(*exc)

    def sample(self, summary: Summary, row: dict[str, Any]) -> None:
        self._summary, self._last = summary, row
        self._live.update(self._render())

    def warn(self, summary: Summary, message: str) -> None:
        self._summary = summary
        self.console.print(f"[yellow]warning:[/] {message}")
        self._live.update(self._render())

    def _render(self) -> Group:
        s = self._summary
        assert s is not None
        grid = Table.grid(padding=(0, 2))
        grid.add_row(Text(self.title, style="bold"),
                     ProgressBar(total=s.total, completed=s.next_sample, width=30),
                     f"{s.next_sample}/{s.total} samples")
        grid.add_row("rate", f"{s.rate_per_min:.1f} samples/min",
                     f"elapsed {_duration(s.elapsed)}   ETA {_duration(s.eta)}")
        lo, hi = s.tension_range
        hot = s.temperature_max
        grid.add_row("tension", f"{lo:.1f} … {hi:.1f} N" if s.written else "–",
                     Text(f"max temperature {hottest(hot)}" if s.written else "",
                          style="red" if hot >= WARN_C else ""))
        if self._last is not None:
            r = self._last
            pose = " ".join(f"{v:+.3f}" for v in r["theta"])
            grid.add_row("last", f"sample {r['sample']}", f"θ = [{pose}] rad")
        problems = f"{len(s.warnings)} warnings, {s.unsettled} unsettled, " \
                   f"{len(s.skipped)} skipped"
        grid.add_row("problems", Text(problems, style="yellow" if s.warnings else "dim"), "")
        return Group(grid)


class LogReporter:
    """Plain progress lines for a log file or pipe (where a live panel draws nothing).

    One complete line for the first sample, then at most one every ``every_s`` seconds and
    one at the end; warnings as they come. The log of a run killed with ``kill -9`` thus
    shows how far it got.
    """

    def __init__(self, console: Console | None = None, title: str = "collect",
                 every_s: float = 5.0) -> None:
        self.console = console or Console(stderr=True)
        self.title, self.every_s = title, every_s
        self._summary: Summary | None = None
        self._printed_at = -float("inf")
        self._printed: int | None = None  # next_sample of the last line printed

    def __enter__(self) -> LogReporter:
        return self

    def __exit__(self, *exc: object) -> None:
        s = self._summary
        if s is not None and self._printed != s.next_sample:
            self._line(s)

    def sample(self, summary: Summary, row: dict[str, Any]) -> None:
        self._summary = summary
        if time.monotonic() - self._printed_at >= self.every_s:
            self._line(summary)

    def warn(self, summary: Summary, message: str) -> None:
        self._summary = summary
        self.console.print(f"warning: {message}", markup=False, highlight=False,
                           soft_wrap=True)

    def _line(self, s: Summary) -> None:
        self._printed_at, self._printed = time.monotonic(), s.next_sample
        parts = [f"{self.title}: {s.next_sample}/{s.total} samples",
                 f"{s.rate_per_min:.1f} samples/min", f"elapsed {_duration(s.elapsed)}"]
        if s.eta is not None and s.next_sample < s.total:
            parts.append(f"ETA {_duration(s.eta)}")
        if s.written:
            lo, hi = s.tension_range
            parts.append(f"tension {lo:.1f}…{hi:.1f} N, max {hottest(s.temperature_max)}")
        parts.append(f"{len(s.warnings)} warnings, {s.unsettled} unsettled, "
                     f"{len(s.skipped)} skipped")
        self.console.print(", ".join(parts), markup=False, highlight=False, soft_wrap=True)


def summary_lines(s: Summary) -> list[str]:
    """The end-of-run summary (also after Ctrl-C, a safety stop or a full disk)."""
    state = ("complete" if s.complete else f"STOPPED: {s.stopped}" if s.stopped
             else f"FAILED: {s.failed}" if s.failed else "incomplete")
    lines = [f"collection {state}", f"  file {s.path}",
             f"  rows in file {s.rows} of {s.total} planned  (this run {s.written}, "
             f"before {s.already}); next sample {s.next_sample}",
             f"  time {_duration(s.elapsed)}, {s.rate_per_min:.1f} samples/min, "
             f"settling {s.settle_time / max(s.written, 1):.2f} s per sample"]
    if s.written:
        lo, hi = s.tension_range
        lines.append(f"  tension {lo:.1f} … {hi:.1f} N, max temperature "
                     f"{hottest(s.temperature_max)}")
    if s.unsettled or s.skipped or s.warnings:
        lines.append(f"  {s.unsettled} unsettled (flagged settled=false), "
                     f"{len(s.skipped)} skipped {s.skipped or ''}, {len(s.warnings)} warnings")
    if not s.complete and s.next_sample < s.total:
        lines.append(f"  continue with the same command plus --resume (--out {s.path})")
    return lines
