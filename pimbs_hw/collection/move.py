"""Getting from one sample to the next without jerks: ramps instead of step commands.

Each board gets its new command a moment after the previous one, and each muscle's elastic
element is exponentially stiff: a step in one muscle's length while its antagonists are still
held at the old pose stretches a wire by millimetres, hundreds of newtons (the mock bus
reproduces this as a saturated loadcell). So we never step. Modes are switched only where the
new command equals what the muscle is doing now, wires are loaded only while the pose is held,
and commands are ramped in small increments at a limited rate:

* ``release``: at the old pose, held muscles ramp to their approach length and the others to
  the approach tension (what the slack removal did, undone), so the move happens at low
  tension where a millimetre of mismatch costs little;
* ``move``: all muscles length-controlled along the straight joint-space path from the current
  pose to the target, at tensions that balance each pose on the way; the model's error at the
  start (measured minus modelled lengths) is blended out along the way, so the first command
  is where the arm is;
* ``take_up_slack``: held muscles ramp from the approach length to the QP length, the others
  from their current tension to the QP tension: first past them (the overshoot of
  ``plan.Target``), then back, so every muscle's last motion has a known direction.

A length command only says where the motor goes; the arm follows as fast as its inertia and
damping let it, and until it has, the wire between them stretches. MyoSuite's finger (joint
damping of 0.5 N·m·s/rad on levers of 2 cm) follows a motor winding at 5 cm/s at a tenth of
that speed, and a 2.5 kg weight on an elbow lever of 1 cm cannot be accelerated that fast at
all: each wire reached its ceiling within a fifth of a second. So a ramp that loads a wire in
length waits for the arm (``run_ramp``): while a length-held wire reads more than its ramp
expects of it (``Ramp.expected``) by more than its allowance (``PACE_SHARE`` of f_max, at most
half the way to the load limit), the command stays where it is until the arm has caught up.
A wire that stays high however long the arm is given (a load the description does not know)
is not waited for again on that ramp; the load limit still watches it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace

import numpy as np
import scipy.linalg

from pimbs_arm.model import ArmModel, InfeasiblePoseError
from pimbs_hw.collection.link import ArmLink, Reading
from pimbs_hw.collection.plan import Target

MOVE_KNOTS = 8  # poses along a move whose balancing tensions are solved (linear between)
# fraction of f_max past which the routine gives a pose up (unloads it and goes on): above
# every command of a plan (PLAN_CEILING 0.9), below the boards' ceiling, which stops it all
LOAD_LIMIT = 0.95
PACE_SHARE = 0.1  # of f_max: how far a length-held wire may run ahead of its arm
PACE_MIN_SHARE = 0.02  # of f_max: the least allowance (noise, a loadcell's hysteresis)
# s of arm time a ramp waits without the arm catching up before it takes the excess for a
# load the description does not know, and goes on
PACE_STALL_S = 0.5
PACE_POLL_S = 0.005  # s between command/read cycles while a ramp waits for the arm
# a load ramp lasts at least this many of the slowest swings of the arm on its held wires:
# a linear ramp over whole swings leaves (nearly) no swing behind, one over a fraction of a
# swing acts as a step
SWING_PERIODS = 2.0
RAMP_CYCLE_S = 0.02  # s: the longest a ramp holds one command (the boards' watchdog: 0.25 s)


@dataclass(frozen=True)
class MoveConfig:
    """Per-cycle increments (bound the damage of board-to-board skew) and rates (the arm's).

    Tension increments and rates are shares of each muscle's f_max (25 N and 1000 N/s for a
    600 N muscle): the ringing a load step excites in an arm grows with the step, and the
    room between the plan's tensions and the boards' ceiling is a share of f_max too.

    ``quasi_static``: the arm has no inertia and no friction in its tension loops (the
    built-in simulated arm, which follows each equilibrium without swinging and takes each
    cycle's commands together): a held wire's length steps are still spaced evenly in tension,
    but as many and as fast as its length change needs, not a tension command's, as nothing
    rings and no board lags another.
    """

    length_step: float = 1e-3             # m per command cycle
    tension_step_of_f_max: float = 1 / 24  # of f_max per command cycle
    length_rate: float = 0.05             # m/s
    tension_rate_of_f_max: float = 5 / 3  # of f_max per second
    speed: float = 1.0                    # time speed-up of a simulated arm: rates scale with it
    quasi_static: bool = False            # the arm cannot ring (see above)

    def meta(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Ramp:
    """Commands in one mode, sent evenly over ``duration`` seconds.

    ``expected`` (commands, M): the tension each length-controlled muscle pulls at each
    command once the arm is where the ramp puts it (NaN: not watched, as tension-controlled
    muscles); ``allowance`` (commands, M): how far above it a wire may read before the ramp
    waits for the arm (``run_ramp``); ``stall_s``: wall seconds of waiting without the arm
    catching up, after which the ramp goes on.
    """

    mode: tuple[str, ...] | str
    commands: list[np.ndarray]
    duration: float
    expected: np.ndarray | None = None
    allowance: np.ndarray | None = None
    stall_s: float = PACE_STALL_S
    unheld: np.ndarray | None = None  # (N,) the first pose on the way no tensions hold


def _ramp(mode, start: np.ndarray, end: np.ndarray, is_length: np.ndarray, cfg: MoveConfig,
          f_max: np.ndarray, path=None, tension_span: np.ndarray | None = None,
          expect: Callable[[float], np.ndarray] | None = None, min_s: float = 0.0) -> Ramp:
    """``tension_span`` (N, per muscle): the tension change a length-mode muscle is expected
    to go through, limited like a tension command's (the steps and the rate) unless the arm
    is quasi-static (``MoveConfig.quasi_static``). ``expect(x)``: the tensions the
    length-controlled muscles pull at ``x`` of the way (NaN: not watched), for the ramp to
    wait for an arm that lags (never for a quasi-static one: it cannot lag, and an excess
    there is a load the description does not know, which waiting never removes)."""
    tension_step = cfg.tension_step_of_f_max * f_max
    tension_rate = cfg.tension_rate_of_f_max * f_max * cfg.speed
    delta = np.abs(end - start)
    steps = delta / np.where(is_length, cfg.length_step, tension_step)
    seconds = delta / np.where(is_length, cfg.length_rate * cfg.speed, tension_rate)
    if tension_span is not None and not cfg.quasi_static:
        steps = np.maximum(steps, tension_span / tension_step)
        seconds = np.maximum(seconds, tension_span / tension_rate)
    if not cfg.quasi_static:
        seconds = np.maximum(seconds, min_s / cfg.speed)
    # a command at least every RAMP_CYCLE_S: the boards' watchdogs are fed by commands, and a
    # ramp stretched to the arm's swing must not hold one command for a whole swing
    n = max(1, int(np.ceil(np.max(steps))), int(np.ceil(np.max(seconds) / RAMP_CYCLE_S)))
    s = np.linspace(0.0, 1.0, n + 1)
    commands = [start + x * (end - start) for x in s] if path is None else [path(x) for x in s]
    commands[-1] = end
    if expect is None or cfg.quasi_static:
        return Ramp(mode, commands, float(np.max(seconds)))
    expected = np.array([np.where(is_length, expect(x), np.nan) for x in s])
    headroom = (LOAD_LIMIT * f_max - expected) / 2
    allowance = np.maximum(np.minimum(PACE_SHARE * f_max, headroom), PACE_MIN_SHARE * f_max)
    return Ramp(mode, commands, float(np.max(seconds)), expected, allowance,
                PACE_STALL_S / cfg.speed)


def _loading(model: ArmModel, theta: np.ndarray, held: np.ndarray, start: np.ndarray,
             end: np.ndarray, cfg: MoveConfig, mode) -> Ramp:
    """Mixed commands from ``start`` to ``end``, held muscles' lengths spaced evenly in the
    tension the model expects of them, not in length.

    An elastic element stiffens with its load (df/dl = K(f + 1)): a millimetre is a few
    newtons near the pretension and hundreds near f_max. Even length steps would load a held
    wire in a few jerks at the top, and under real dynamics (an arm with inertia and little
    damping) each jerk rings; even tension steps load it as gently as a tension command.
    """
    # A held muscle's length l pulls f(h - l), as the model sees it, at most f_max: a length
    # read while the arm is far from theta (a pose given up mid-swing) gives a stretch whose
    # exponential tension no wire carries, and steps spaced in it would never end.
    h, cap = model.h_geom(theta), model.stretch(model.f_max)
    f0 = np.where(held, model.tension_from_stretch(np.minimum(h - start, cap)), 0.0)
    f1 = np.where(held, model.tension_from_stretch(np.minimum(h - end, cap)), 0.0)
    s0, s1 = model.stretch(f0), model.stretch(f1)
    moving = held & (np.abs(s1 - s0) > 1e-12)

    def path(x: float) -> np.ndarray:
        w = np.where(moving, (model.stretch(f0 + x * (f1 - f0)) - s0)
                     / np.where(moving, s1 - s0, 1.0), x)
        return start + w * (end - start)

    swing = 0.0 if cfg.quasi_static else swing_period(model, theta, held, (f0 + f1) / 2)
    return _ramp(mode, start, end, held, cfg, model.f_max, path,
                 np.where(held, np.abs(f1 - f0), 0.0), lambda x: f0 + x * (f1 - f0),
                 SWING_PERIODS * swing)


def swing_period(model: ArmModel, theta: np.ndarray, held: np.ndarray,
                 tension: np.ndarray) -> float:
    """s: the slowest swing of the arm at ``theta`` on its ``held`` wires at ``tension`` (the
    description's inertia against the wires' stiffness K(f + 1) through their moment arms;
    tension-controlled wires pull the same whatever the arm does and add none). 0 where no
    held wire makes a spring of the arm (nothing to swing against).

    Loading the tension-controlled wires of a pose against its held ones is a push on that
    spring: MyoSuite's elbow with a 2.5 kg weight in the hand swings 0.4 s on its biceps, and
    its triceps loaded in 0.3 s swung it open until the biceps reached the boards' ceiling."""
    if not held.any():
        return 0.0
    G = model.muscle_jacobian(theta)[held]
    stiffness = G.T @ ((model.K[held] * (np.maximum(tension[held], 0.0) + 1.0))[:, None] * G)
    try:
        w2 = scipy.linalg.eigh(stiffness, model.inertia(theta), eigvals_only=True)
    except (np.linalg.LinAlgError, ValueError):  # no inertia to speak of: nothing swings
        return 0.0
    w2 = w2[w2 > 1e-9 * max(float(w2.max(initial=0.0)), 1e-300)]
    return 0.0 if not w2.size else float(2.0 * np.pi / np.sqrt(w2.min()))


def release(model: ArmModel, now: Reading, previous: Target, cfg: MoveConfig,
            theta: np.ndarray | None = None) -> Ramp:
    """Unload the old pose: the slack removal of ``previous`` run backwards, at ``theta``,
    where the arm is (default: the pose).

    Each muscle starts where it is (bumpless), a tension-controlled one at no more than the
    plan ever asked of it: a wire reading far above its command (snagged, or mid-swing when
    a pose is given up) is not to be held there. Held muscles end at the approach tensions'
    lengths of where the arm is: a pose given up on the way to it (the arm short of the pose,
    a wire at the load limit) is unloaded there, not wound on towards the pose it could not
    reach.
    """
    theta = previous.theta if theta is None else np.asarray(theta, float)
    asked = np.maximum(previous.hold_command, previous.overshoot_command)
    start = np.where(previous.held, now.length, np.minimum(now.tension, asked))
    pretension = _pretension(model, previous)
    end = np.where(previous.held, model.length(theta, pretension), pretension)
    return _loading(model, theta, previous.held, start, end, cfg, previous.hold_mode)


def _pretension(model: ArmModel, target: Target) -> np.ndarray:
    """The approach tensions the approach lengths were computed for."""
    return model.tension_from_stretch(model.h_geom(target.theta) - target.approach_length)


def move(model: ArmModel, now: Reading, theta_now: np.ndarray, target: Target,
         cfg: MoveConfig, balance: Callable[..., np.ndarray] | None = None) -> Ramp:
    """Length commands from where the arm is to ``target.approach_length``.

    ``balance(θ, floor)``: the lowest tensions of at least ``floor`` (None: the muscles' own
    floors) that hold θ. With it, the tensions the lengths are computed for hold each pose
    the path passes (solved at ``MOVE_KNOTS`` poses with floors blended from the start's
    tensions to the approach's, else at the muscles' own floors; linear between them); the
    start's own imbalance (measured tensions) is blended out. Where a pose on the way cannot
    be held at all, the tensions there blend linearly from the start's to the end's, and the
    ramp names the first such pose (``Ramp.unheld``). Lengths at unbalanced tensions put
    the arm where those tensions balance instead, and on an arm with a soft direction (the
    two proximal joints of MyoSuite's finger) that was far enough off the path for the arm
    to end beside the target's approach, in another rest position of the same lengths.
    """
    f_now = np.maximum(now.tension, 0.0)
    f_end = _pretension(model, target)
    start_error = now.length - model.length(theta_now, f_now)
    knots = np.linspace(0.0, 1.0, MOVE_KNOTS + 1)
    along = np.outer(1.0 - knots, f_now) + np.outer(knots, f_end)  # (knots, M)
    unheld = None
    if balance is not None:
        held = along.copy()
        for k, s in enumerate(knots):
            theta = theta_now + s * (target.theta - theta_now)
            for floor in (along[k], None):
                try:
                    held[k] = balance(theta, floor)
                    break
                except InfeasiblePoseError:
                    pass
            else:
                if unheld is None:
                    unheld = theta
        along = held + np.outer(1.0 - knots, f_now - held[0])

    def tension(s: float) -> np.ndarray:
        return np.array([np.interp(s, knots, column) for column in along.T])

    def path(s: float) -> np.ndarray:
        theta = theta_now + s * (target.theta - theta_now)
        return model.length(theta, tension(s)) + (1.0 - s) * start_error

    grid = np.linspace(0.0, 1.0, 4 * MOVE_KNOTS + 1)
    span = _stiff_travel(model, np.array([path(x) for x in grid]),
                         np.array([tension(x) for x in grid]))
    ramp = _ramp("length", now.length, target.approach_length,
                 np.ones(model.n_muscles, bool), cfg, model.f_max, path, span, tension)
    return replace(ramp, unheld=unheld)


def _stiff_travel(model: ArmModel, lengths: np.ndarray, tensions: np.ndarray) -> np.ndarray:
    """(M,) N: the tension each wire would gain if the arm stood still while its motor went
    along ``lengths`` (points, M) at the stiffness of ``tensions`` (points, M), df/dl =
    K(f + 1): a ramp limited in it like a tension command loads a wire no faster than a
    tension command would, however slowly the arm follows."""
    f = np.maximum((tensions[1:] + tensions[:-1]) / 2, 0.0)
    return np.sum(np.abs(np.diff(lengths, axis=0)) * model.K * (f + 1.0), axis=0)


def take_up_slack(model: ArmModel, now: Reading, target: Target, cfg: MoveConfig,
                  end: np.ndarray | None = None) -> Ramp:
    """Mixed commands in ``target.hold_mode`` from the current readings to the holding.

    ``end`` (default ``target.hold_command``): the overshoot of the holding that the final
    approach comes back from (``plan.Target.overshoot_command``).
    """
    start = np.where(target.held, now.length, now.tension)
    end = target.hold_command if end is None else end
    return _loading(model, target.theta, target.held, start, end, cfg, target.hold_mode)


def run_ramp(link: ArmLink, ramp: Ramp) -> Reading:
    """Send the commands evenly over the ramp's duration, reading (limits checked) each cycle.

    A host that fell behind (descheduled, a slow read) shifts the rest of the schedule instead
    of sending the missed commands in a burst: the rates are the arm's, whatever the host did.
    """
    t0 = time.monotonic()
    last = max(len(ramp.commands) - 1, 1)
    interval = ramp.duration / last
    reading = None
    known = np.zeros(len(ramp.commands[0]))  # excess a stalled wait left: a load not modelled
    for k, command in enumerate(ramp.commands):
        wait = t0 + interval * k - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        elif -wait > interval:
            t0 -= wait  # re-time: this command goes now, the next one an interval later
        link.command(ramp.mode, command)
        reading = link.read()
        if ramp.expected is not None:
            reading, waited = _wait_for_arm(link, ramp, k, reading, known)
            t0 += waited  # the rest of the schedule follows the arm
    assert reading is not None
    return reading


def _wait_for_arm(link: ArmLink, ramp: Ramp, k: int, reading: Reading, known: np.ndarray
                  ) -> tuple[Reading, float]:
    """Hold command ``k`` while a length-controlled wire reads more than the ramp expects of
    it by more than its allowance, until it is back within half the allowance (the arm has
    caught up) or the excess stops falling for ``ramp.stall_s`` (the rest is a load the
    description does not know: added to ``known`` and not waited for again); (the last
    reading, seconds waited)."""
    assert ramp.expected is not None and ramp.allowance is not None
    expected, allowance = ramp.expected[k] + known, ramp.allowance[k]
    watched = np.isfinite(expected)
    if not (watched & (reading.tension - expected > allowance)).any():
        return reading, 0.0
    start = progress_at = time.monotonic()
    least = np.inf
    while True:
        time.sleep(PACE_POLL_S)
        link.command(ramp.mode, ramp.commands[k])
        reading = link.read()
        behind = np.where(watched, (reading.tension - expected) / allowance - 0.5, 0.0)
        if (behind <= 0).all():
            break
        now, lag = time.monotonic(), float(np.maximum(behind, 0.0).sum())
        if lag < least - 0.05:
            least, progress_at = lag, now
        elif now - progress_at >= ramp.stall_s:
            known += np.maximum(behind, 0.0) * allowance
            break
    return reading, time.monotonic() - start
