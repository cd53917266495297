"""`pimbs collect`: record a body-schema data set on the arm (or the simulated arm).

A thin shell over ``pimbs_hw.collection``: parse options, connect, run with a live display,
and always end with a summary. Exit status: 0 complete, 1 stopped by an error or a run that
recorded nothing or gave up most of its poses (the message says what to do), 130
interrupted by Ctrl-C. In every case the file holds every finished sample and ``--resume``
continues it.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import click

from pimbs_cli.common import (
    check_output,
    load_usable_arm,
    plant_damping_option,
    robot_option,
    rows_as_samples,
    user_errors,
)


def _default_out(robot: str) -> Path:
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    name = Path(robot).name.removesuffix(".muscles.yaml").removesuffix(".xml")
    return Path(f"collection-{name}-{stamp}.parquet")


def _raise_interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


@contextlib.contextmanager
def _stop_on_signals() -> Iterator[None]:
    """Ctrl-C and SIGTERM both end the run cleanly (arm relaxed, file closed, summary).

    Installed explicitly: a shell starts background jobs with SIGINT ignored, and the
    default SIGTERM would skip the relax and the summary.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, _raise_interrupt) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


@click.command("collect")
@click.option("--port", required=True,
              help="where the boards are: can0 (socketcan), pcan:PCAN_USBBUS1, "
                   "slcan:/dev/ttyACM0, /dev/ttyUSB0 (serial), or virtual (slcan-pty: through "
                   "an emulated SLCAN adapter) for the simulated arm")
@click.option("--samples", "-n", type=click.IntRange(min=1), default=496, show_default=True,
              help="poses in the recording (the paper's real arm: 496); --resume continues "
                   "towards the same number")
@robot_option()
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path),
              help="recording to write [default: collection-ROBOT-UTCTIME.parquet]")
@click.option("--seed", type=int, default=0, show_default=True,
              help="pose sequence; the same seed gives the poses of `pimbs simulate --seed`")
@click.option("--map", "map_kind", type=click.Choice(["atl", "al"]), default="atl",
              show_default=True, help="atl: tension floors uniform in [10, 300] N (at most 3/4 "
                                      "of the weakest muscle's f_max) per sample (as simulate); "
                                      "al: each muscle's f_floor")
@click.option("--resume", is_flag=True,
              help="continue an interrupted --out file (same --seed/--samples/--robot/--map)")
@click.option("--fault", "faults", multiple=True, metavar="KIND:MUSCLE@SAMPLE",
              help="simulated arm only: inject a fault, e.g. silent-board:m1@5, overheat:m2@10")
@click.option("--conceal", multiple=True, metavar="EFFECT[:PARAMS]",
              help="simulated arm only: the arm carries this unlabelled effect, e.g. "
                   "tension_offset:20,muscles=m1 (see pimbs simulate --help)")
@click.option("--settle-tol", type=click.FloatRange(min=0, min_open=True), default=1.0,
              show_default=True, help="N: tension drift / error counted as settled")
@click.option("--settle-length-tol", type=click.FloatRange(min=0, min_open=True),
              default=3e-5, show_default=True, help="m: length drift / error counted as settled")
@click.option("--settle-window", type=click.FloatRange(min=0), default=0.1, show_default=True,
              help="s of readings that must be quiet")
@click.option("--settle-timeout", type=click.FloatRange(min=0, min_open=True), default=5.0,
              show_default=True, help="s; an unsettled sample is recorded, flagged and warned")
@click.option("--fixed-wait", type=click.FloatRange(min=0), default=None,
              help="s: wait this long before each reading instead of detecting settling")
@click.option("--schema", "schema_dir", type=click.Path(file_okay=False, path_type=Path),
              default=None,
              help="command the poses with this learned body schema (a `pimbs train --out` "
                   "directory) instead of the geometric model; samples where it would "
                   "extrapolate or be unsafe fall back to the model, with a warning")
@click.option("--plant", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="simulated arm only: an MJCF that MuJoCo integrates as the true arm "
                   "(mj_step dynamics; may differ from --robot, as a real arm does)")
@plant_damping_option()
@click.option("--mock-speed", type=click.FloatRange(min=0, min_open=True), default=1.0,
              show_default=True, help="simulated arm only: time speed-up of its dynamics")
@click.option("--poses-file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="collect these poses instead of the seeded sequence, one sample per row "
                   "(CSV: a column per joint, optionally floor_<muscle> columns; `pimbs "
                   "diagnose --poses-out` writes one)")
@click.option("--calibration", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="encoder zeros from `pimbs zero` [default: ROBOT.calibration.yaml beside "
                   "the robot file (here for a built-in robot) when it exists]")
@user_errors
def command(port: str, samples: int, robot: str, out: Path | None, seed: int, map_kind: str,
            resume: bool, faults: tuple[str, ...], conceal: tuple[str, ...],
            settle_tol: float, settle_length_tol: float, settle_window: float,
            settle_timeout: float, fixed_wait: float | None, schema_dir: Path | None,
            plant: Path | None, plant_damping: str, mock_speed: float,
            calibration: Path | None, poses_file: Path | None = None) -> None:
    """Collect SAMPLES static poses: move, remove slack, settle, read, write one row each.

    Every row is on disk before the next pose, so Ctrl-C, kill -9, a power cut or a full disk
    lose at most the sample in progress; --resume continues the same seeded sequence.
    """
    from pimbs_arm.poses import replaced_note, scaled_note
    from pimbs_hw import is_simulated
    from pimbs_hw.collection.move import MoveConfig
    from pimbs_hw.collection.resume import collection_meta, open_recording
    from pimbs_hw.collection.settle import SettleConfig
    from pimbs_hw.mock.faults import parse_faults
    from pimbs_recording.writer_lock import writer_lock

    simulated = is_simulated(port)
    if (faults or conceal or plant) and not simulated:
        raise click.UsageError(f"--fault, --conceal and --plant act on the simulated arm only; "
                               f"use --port virtual, not {port!r}")
    if resume and out is None:
        raise click.UsageError("--resume needs --out FILE (the recording to continue)")
    model = load_usable_arm(robot)  # the checks `simulate` runs
    parse_faults(faults, model.muscles)  # refuse a bad spec before touching the arm
    out = out or _default_out(robot)
    check_output(out, force=True, what="recording")  # no directory made for a mistyped path
    if poses_file is not None:
        plan, schema_meta = _file_plan(model, poses_file, samples, seed, map_kind, schema_dir)
    else:
        plan, schema_meta = _plan(model, samples, seed, map_kind, schema_dir)
    samples = plan.n_samples
    if schema_dir is not None and any(c.startswith("routing") and "seed=" not in c
                                      for c in conceal):
        click.echo(f"note: the concealed routing is drawn from --seed {seed}, so it is the "
                   "arm the schema was learned on only if that collection used the same "
                   "seed; name the arm in both: --conceal routing:MAG,seed=S", err=True)
    settle = SettleConfig(tension_tol=settle_tol, length_tol=settle_length_tol,
                          window=settle_window, timeout=settle_timeout, fixed_wait=fixed_wait)
    moves = MoveConfig(speed=mock_speed if simulated else 1.0)
    if plan.replaced:
        click.echo(replaced_note(plan.replaced, samples, seed), err=True)
    if plan.scaled:
        click.echo(scaled_note(plan.scaled, samples), err=True)
    rings, damping = (("", {}) if plant is None else
                      _plant_notes(plant, model, settle.timeout, plant_damping == "calm"))
    # the simulated arm the rows came from: its file, and the joint damping it was given
    plant_meta = {} if plant is None else {"plant": str(plant.resolve()),
                                           **({"plant_joint_damping": damping} if damping
                                              else {})}
    meta = collection_meta(model, {**plan.meta(), **schema_meta, **plant_meta}, port=port,
                           simulated=simulated, settle=settle.meta(), move=moves.meta())
    hold = _relax_note(model, simulated)
    zero_m, note = _zeros(model.robot, calibration, simulated)
    # one writer per recording for the whole run: a second collect (or --resume) on the same
    # file is refused before it reads or writes anything, instead of dropping samples
    with writer_lock(out):
        writer, start = open_recording(out, meta, resume)
        if start >= samples:
            click.echo(f"{out} already holds all {samples} samples; nothing to do")
            return
        with _stop_on_signals():
            _run(port, model, plan, writer, start, settle, moves, faults, conceal, seed,
                 zero_m, note, plant, hold, rings, damping)


def _plant_notes(plant: Path, model, wait_s: float, calm: bool) -> tuple[str, dict]:
    """Before the arm moves: one line when the plant arm rings longer than a pose may settle
    (and is calmed, ``calm``, or only warned about), one when it must be integrated with a
    finer timestep than its file's (and a plant that does not fit the description is
    refused here, before connecting). Returns the ringing warning ('' if none, or calmed),
    for a stop to name the swing as its cause, and the joint damping the plant runs with."""
    from pimbs_hw.mock.mujoco_plant import plant_notes

    rings, step, damping = plant_notes(plant, model.robot, wait_s, calm)
    for note in (rings, step):
        if note:
            click.echo(note, err=True)
    return ("" if calm else rings), damping


def _relax_note(model, simulated: bool) -> bool:
    """Whether relaxing would let the arm fall out of its routed range: then one line says so
    before the arm is touched, and the collection holds the arm instead (True)."""
    from pimbs_hw.collection.relax import relax_fall

    fall = relax_fall(model)
    if fall is None:
        return False
    arm = "the simulated arm" if simulated else "the arm"
    click.echo(f"note: {fall}; the collection holds {arm} at its motors' lengths instead of "
               "relaxing it when it connects and between poses. The boards still relax it when "
               "the collection ends or stops: support it then", err=True)
    return True


def _plan(model, samples: int, seed: int, map_kind: str, schema_dir: Path | None):
    """The geometric plan, or the learned schema's (and the metadata that says which)."""
    from pimbs_hw.collection.plan import CollectionPlan

    if schema_dir is None:
        return CollectionPlan(model, samples, seed, map_kind), {}
    from pimbs_hw.collection.schema_plan import SchemaPlan
    from pimbs_learn import load_body_schema
    from pimbs_learn.data import file_sha256
    from pimbs_learn.io import WEIGHTS

    schema = load_body_schema(schema_dir)
    plan = SchemaPlan(model, schema, samples, seed, map_kind)
    return plan, {"schema": str(schema_dir),
                  "schema_weights_sha256": file_sha256(schema_dir / WEIGHTS)}


def _file_plan(model, poses_file: Path, samples: int, seed: int, map_kind: str,
               schema_dir: Path | None):
    """The plan of a poses file (its rows set the sample count), and its metadata."""
    from pimbs_arm.poses_file import read_pose_plan
    from pimbs_hw.collection.plan import CollectionPlan

    if schema_dir is not None:
        raise click.UsageError("--poses-file and --schema do not go together: the file's "
                               "poses are commanded with the geometric model")
    poses = read_pose_plan(poses_file, model, seed, map_kind)
    rows = rows_as_samples(samples, len(poses.poses), poses_file)
    return (CollectionPlan(model, rows, seed, map_kind, poses=poses),
            {"poses_file": str(poses_file)})


def _zeros(robot, calibration: Path | None, simulated: bool) -> tuple[object, str | None]:
    """Encoder zeros to apply (the named file, else the robot's default one if present),
    and the line to show once the arm is connected."""
    from pimbs_calibration.zeroing import default_path, load

    path = calibration or default_path(robot)
    if calibration is None and (simulated or not path.exists()):
        return None, (None if simulated else f"note: no {path}; encoders are used as they "
                      "read (run `pimbs zero` on a real arm first)")
    return load(path, robot), f"encoder zeros from {path}"


def _run(port, model, plan, writer, start, settle, moves, faults, conceal, seed,
         zero_m=None, note=None, plant=None, hold=False, rings="", damping=None) -> None:
    """Connect, collect with the live panel, and report however it ends."""
    from rich.console import Console

    from pimbs_hw.collection.progress import LiveReporter, LogReporter, summary_lines
    from pimbs_hw.collection.routine import Collector
    from pimbs_hw.collection.session import open_link, simulation_cause, stop_advice
    from pimbs_hw.safety import SafetyStop
    from pimbs_recording.format import RecordingWriteError

    console = Console(stderr=True)
    collector = link = None
    error: str | None = None  # the full message: what happened and what to do
    reason: str | None = None  # what happened, for the summary
    try:
        with open_link(port, model.robot, faults=faults, conceal=conceal, seed=seed,
                       speed=moves.speed, zero_m=zero_m, plant=plant,
                       plant_damping=damping, hold=hold) as link:
            if note:
                console.print(note)
            collector = Collector(link, model, plan, writer, start, settle, move=moves,
                                  relax_safe=not hold)
            if start:
                console.print(f"resuming {writer.path} at sample {start} of {plan.n_samples}")
            # a live panel on a terminal; plain lines in a log, so a killed run shows progress
            reporter_type = LiveReporter if console.is_terminal else LogReporter
            with reporter_type(console) as reporter:
                collector.reporter = reporter
                collector.run()
    except KeyboardInterrupt:
        if collector is not None:
            collector.summary.stopped = "interrupted (Ctrl-C); the arm was relaxed"
    except SafetyStop as stop:
        stop = simulation_cause(stop, link)
        sample = collector.summary.next_sample if collector is not None else None
        reason, error = str(stop), stop_advice(stop, plan, sample, rings)
    except RecordingWriteError as exc:
        reason = str(exc)
        error = (f"{exc}. The arm was relaxed; samples written so far are safe. "
                 f"Free disk space, then rerun with --resume.")
    if collector is not None:
        if reason:
            collector.summary.stopped = reason
        for line in summary_lines(collector.summary):
            click.echo(line)
    if error:
        raise click.ClickException(error)
    summary = None if collector is None else collector.summary
    if summary is not None and summary.failed and summary.unheld_ways > len(summary.skipped) / 2:
        raise click.ClickException(
            f"{summary.failed}: the muscles cannot carry the arm from where it stood to its "
            "poses (the warnings above name a pose on each way). Narrow the joint ranges in "
            "the muscle file to where they hold the arm (`pimbs robot "
            f"{model.robot.muscle_path}` shows what each pulls), or give them a higher f_max")
    if summary is not None and summary.failed:
        raise click.ClickException(
            f"{summary.failed}: the arm did not stay at the poses the description "
            f"plans (the warnings above say why each was given up). Check the description "
            f"against the arm with `pimbs robot {model.robot.muscle_path}`, or collect with "
            "--map al (lower tensions)")
    if collector is None or not collector.summary.complete:
        sys.exit(130)  # SystemExit: not turned into an error message by user_errors
