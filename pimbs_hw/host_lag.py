"""How long this process could not run Python code: time in which no board can be blamed.

A board is silent when it sent nothing while the host could have heard it. When this process
cannot run — other work has every core, or one call holds Python's GIL for a long time — its
receive thread does not run, so frames a board did send sit unread and look late; and
simulated boards, which run in this very process, do not run either. A wall-clock watchdog
would blame a board for the host's own stall.

``HostLag`` measures those stalls the way an event loop measures its lag: a daemon thread
that sleeps ``period_s`` again and again and adds up how much later than asked it got to run
(beyond ``grace_s``, the ordinary wake-up and GIL hand-over). It is a light thread, like the
simulated boards' loop and the driver's reads, so its lateness is theirs: on an idle machine a
CPU-bound thread beside it (a plan being computed) costs it a few milliseconds, as the GIL
changes hands every 5 ms; a starved process, or a thread descheduled while it holds the GIL
(on a loaded machine), costs it, and them, the whole stall. ``starved(t0, t1)`` is the
stalled part of ``[t0, t1]``; ``total(now)`` the running sum, for a clock that stands still
while the process cannot run (the simulated boards', ``pimbs_hw.mock.arm``). A stall still
in progress (the probe overdue) counts as far as it has gone. One probe serves the whole
process (``host_lag()``); it needs nothing from the operating system, so it works anywhere.
"""

from __future__ import annotations

import bisect
import threading
import time


class HostLag:
    """Cumulative time this process could not run Python code, measured by a probe thread.

    ``keep_s``: how far back ``starved`` can look (an older start counts from the oldest
    record kept, i.e. less stall, never more).
    """

    def __init__(self, period_s: float = 0.01, grace_s: float = 0.01,
                 keep_s: float = 120.0) -> None:
        self.period_s, self.grace_s, self.keep_s = period_s, grace_s, keep_s
        self._lock = threading.Lock()
        self._times: list[float] = []  # the probe's wake-ups (time.monotonic())
        self._totals: list[float] = []  # the stall sum at each
        self._thread: threading.Thread | None = None

    def _ensure_running(self) -> None:
        """Start the probe (again, after a fork, whose child has no copy of the thread)."""
        if self._thread is not None and self._thread.is_alive():
            return
        with self._lock:
            if self._thread is not None and self._thread.is_alive():
                return
            now = time.monotonic()
            total = self._totals[-1] if self._totals else 0.0
            self._times.clear()
            self._totals.clear()
            self._times.append(now)
            self._totals.append(total)
            self._thread = threading.Thread(target=self._run, name="pimbs-host-lag",
                                            daemon=True)
            self._thread.start()

    def _run(self) -> None:
        while True:
            time.sleep(self.period_s)
            now = time.monotonic()
            with self._lock:
                late = now - self._times[-1] - self.period_s
                total = self._totals[-1] + max(0.0, late - self.grace_s)
                self._times.append(now)
                self._totals.append(total)
                if now - self._times[0] > 2 * self.keep_s:  # trim now and then, not per wake
                    k = bisect.bisect_left(self._times, now - self.keep_s)
                    del self._times[:k], self._totals[:k]

    def _at(self, t: float) -> float:
        """The stall sum at time ``t``, interpolated between the probe's records; beyond the
        last record, a stall in progress counts as far as it has gone."""
        times, totals = self._times, self._totals
        k = bisect.bisect_right(times, t)
        if k == 0:
            return totals[0]
        if k == len(times):
            overdue = t - times[-1] - self.period_s - self.grace_s
            return totals[-1] + max(0.0, overdue)
        t0, t1 = times[k - 1], times[k]
        gained = totals[k] - totals[k - 1]
        # the probe's lateness lies at the end of its sleep: the stall ends at t1
        stalled_from = t1 - gained
        return totals[k - 1] + max(0.0, min(t, t1) - max(t0, stalled_from))

    def total(self, now: float) -> float:
        """Seconds this process could not run, from the probe's start to ``now``."""
        self._ensure_running()
        with self._lock:
            return self._at(now)

    def starved(self, t0: float, t1: float) -> float:
        """Seconds of ``[t0, t1]`` (time.monotonic()) in which this process could not run."""
        if t1 <= t0:
            return 0.0
        self._ensure_running()
        with self._lock:
            return min(max(self._at(t1) - self._at(t0), 0.0), t1 - t0)


_PROCESS = HostLag()


def host_lag() -> HostLag:
    """The probe of this process (started on first use)."""
    return _PROCESS
