"""What every `pimbs` command shares: clean error reporting and robot loading.

A researcher at the arm should see one line that says what is wrong and what to do, never
a traceback, for anything the input can get wrong. Programming errors still show their
traceback (they are ours to fix).
"""

from __future__ import annotations

import contextlib
import functools
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import click

F = TypeVar("F", bound=Callable[..., Any])

# Exceptions whose message is written for the user (they name the file/field/port/board).
USER_ERRORS: tuple[type[BaseException], ...] = (ValueError, OSError, RuntimeError)


def user_errors(func: F) -> F:
    """Turn user-facing exceptions into a clean `Error: ...` and exit status 1."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except click.ClickException:
            raise
        except USER_ERRORS as exc:
            raise click.ClickException(str(exc) or exc.__class__.__name__) from exc

    return wrapper  # type: ignore[return-value]


def _known_robot(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """A --robot that is neither a built-in robot nor a file is the option's error, named as
    such (not a field of some description)."""
    from pimbs_calibration.description import RobotNotFoundError, builtin_robots

    if value is None or value in builtin_robots() or Path(value).is_file():
        return value
    raise click.BadParameter(str(RobotNotFoundError(value)), ctx=ctx, param=param)


def robot_option(default: str | None = "two-link-4-muscle") -> Callable[[F], F]:
    """`--robot NAME|PATH`: a built-in robot name, a `.muscles.yaml` or an MJCF `.xml`."""
    return click.option("--robot", default=default, show_default=default is not None,
                        callback=_known_robot,
                        help="built-in robot name (two-link-4-muscle, left-arm-5dof), path "
                             "to a .muscles.yaml robot description, or an MJCF .xml")


def load_usable_arm(robot: str) -> Any:
    """The ``ArmModel`` that `pimbs simulate` and `pimbs collect` run on: the description,
    refused in one line where it fails a check (``pimbs_arm.routing.usable_problem``, which
    `pimbs robot` marks in place). One function for both commands, so neither accepts a
    description the other refuses."""
    from pimbs_arm.model import ArmModel
    from pimbs_arm.routing import usable_problem
    from pimbs_calibration.description import load_robot

    arm = ArmModel(load_robot(robot), check=False)
    problem = usable_problem(arm)
    if problem:
        raise click.ClickException(f"{arm.robot.muscle_path}: {problem}; `pimbs robot "
                                   f"{robot}` shows the moment arms and the poses")
    return arm


def force_option() -> Callable[[F], F]:
    """`--force`: the only way any command replaces an existing recording, model or file."""
    return click.option("--force", is_flag=True,
                        help="replace the output if it already exists")


def plant_damping_option() -> Callable[[F], F]:
    """`--plant-damping`: whether a barely damped MuJoCo plant gets the joint damping a real
    arm's drives give it (its file's muscle actuators, which would damp it, are off)."""
    return click.option("--plant-damping", type=click.Choice(["calm", "file"]), default="calm",
                        show_default=True,
                        help="with --plant: calm gives the joints of a plant that rings longer "
                             "than a pose may settle the damping a real arm's drives give it "
                             "(said in one line); file runs the plant's own damping")


def check_output(path: Path, *, force: bool, what: str = "file",
                 option: str = "--out") -> Path:
    """Refuse, before any work is done, an output that would overwrite or cannot be written.

    Nothing is overwritten without ``--force`` and no directory is created on the user's
    behalf: a typo in a path should fail in one line, not silently write elsewhere.
    """
    path = Path(path)
    if path.exists() and not force:
        raise click.ClickException(
            f"{option} {path}: a {what} already exists there; pass --force to replace it "
            "or choose another path")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise click.ClickException(
            f"{option} {path}: directory {parent} does not exist; create it first")
    return path


class LogProgress:
    """Plain progress lines for output that is not a terminal (log files, pipes, CI).

    A live display draws nothing useful into a log; this prints one complete, flushed line
    at most every ``every_s`` seconds (and at the end) with the count, rate and ETA, so the
    log of a run killed with ``kill -9`` still shows how far it got.
    """

    def __init__(self, label: str, total: int | None, unit: str, *,
                 every_s: float = 5.0, echo: Callable[[str], None] | None = None) -> None:
        self.label, self.total, self.unit, self.every_s = label, total, unit, every_s
        self._echo = echo or (lambda line: click.echo(line, err=True))
        self._start = time.monotonic()
        self._last = -float("inf")
        self._last_line: tuple[int, str] | None = None

    def update(self, done: int, extra: str = "", *, final: bool = False) -> None:
        now = time.monotonic()
        if not final and now - self._last < self.every_s:
            return
        if final and self._last_line == (done, extra):
            return  # the last line printed already says this
        self._last, self._last_line = now, (done, extra)
        elapsed = now - self._start
        rate = done / elapsed if elapsed > 0 else 0.0
        parts = [f"{self.label}: {done}" + (f"/{self.total}" if self.total else "")
                 + f" {self.unit}", f"{_rate(rate)} {self.unit}/s", f"elapsed {_clock(elapsed)}"]
        if self.total and rate > 0 and done < self.total:
            parts.append(f"ETA {_clock((self.total - done) / rate)}")
        if extra:
            parts.append(extra)
        self._echo(", ".join(parts))


@contextlib.contextmanager
def progress(label: str, total: int | None, unit: str, *, console: Any = None,
             every_s: float = 5.0) -> Iterator[Callable[..., None]]:
    """``update(done, extra="")`` for a long loop: a transient rich bar on a terminal,
    :class:`LogProgress` lines otherwise (and a last line however the loop ends).

    A run that fails before anything was done prints no progress line: its error is the
    one line to read.

    ``console`` is the rich console the command prints through (stderr by default); it
    decides what counts as a terminal, so ``FORCE_TERMINAL``/``NO_COLOR`` are honoured.
    """
    from rich.console import Console

    console = console or Console(stderr=True)
    if console.is_terminal:
        from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

        with Progress(TextColumn("{task.description}"), BarColumn(),
                      TextColumn(f"{{task.completed}}/{{task.total}} {unit}"),
                      TimeRemainingColumn(), console=console, transient=True) as bar:
            task = bar.add_task(label, total=total)

            def draw(done: int, extra: str = "") -> None:
                bar.update(task, completed=done,
                           description=f"{label} {extra}" if extra else label)

            yield draw
        return
    log = LogProgress(label, total, unit, every_s=every_s)
    last = [0, ""]

    def line(done: int, extra: str = "") -> None:
        last[:] = [done, extra]
        log.update(done, extra)

    try:
        yield line
    except BaseException:
        if last[0]:  # how far a failed run got; nothing for one that failed before starting
            log.update(last[0], last[1], final=True)
        raise
    log.update(last[0], last[1], final=True)


def _rate(rate: float) -> str:
    return f"{rate:.0f}" if rate >= 100 else f"{rate:.3g}"


def _clock(seconds: float) -> str:
    s = int(round(seconds))
    if s >= 3600:
        return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"
    return f"{s // 60}:{s % 60:02d}"


def rows_as_samples(samples: int, rows: int, poses_file: Path) -> int:
    """A poses file sets the sample count (one per row); ``--samples`` given beside it must
    agree."""
    source = click.get_current_context().get_parameter_source("samples")
    if source == click.core.ParameterSource.COMMANDLINE and samples != rows:
        raise click.UsageError(f"--samples {samples} but {poses_file} holds {rows} poses; "
                               "leave --samples out (one sample per row)")
    return rows
