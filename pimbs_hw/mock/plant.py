"""The true arm behind the simulated boards: static equilibrium + first-order settling.

Each new set of motor commands is solved for the arm's static equilibrium
(``ArmModel.equilibrium``, 10-60 ms) in a solver thread, so the board firmware loop keeps
answering frames meanwhile; the state then relaxes toward that equilibrium with time constant
``tau_s / speed`` (a speed factor > 1 makes tests and demos fast). Temperature rises with load.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, replace

import numpy as np

from pimbs_recording.approach import FrictionPlay

log = logging.getLogger(__name__)


# °C above ambient a motor settles at while its wire holds f_max: each board's motor is sized
# for its muscle, so the heating per newton follows 1/f_max (0.05 °C/N on a 600 N muscle). A
# fixed heating per newton would cook a 2500 N muscle's motor at 40 % of its f_max and
# never warm a 10 N one.
HEAT_AT_F_MAX_C = 30.0


def heat_per_newton(model, at_f_max_c: float = HEAT_AT_F_MAX_C) -> np.ndarray:
    """(M,) °C per N of held tension at steady state, each muscle's motor sized for its f_max."""
    return at_f_max_c / np.asarray(model.f_max, dtype=float)


@dataclass(frozen=True)
class PlantState:
    theta: np.ndarray  # (N,) rad, true pose
    tension: np.ndarray  # (M,) N, true (joint-side) tension
    length: np.ndarray  # (M,) m, motor-side length
    temperature: np.ndarray  # (M,) °C
    approach: np.ndarray  # (M,) friction state in [-1, 1]: +1 paid out last, -1 pulled in


def thermal_step(temperature: np.ndarray, tension: np.ndarray, ambient_c: np.ndarray,
                 heat_c_per_n: np.ndarray | float, heat_rate_c_per_s: np.ndarray, dt_arm: float,
                 dt: float, tau_thermal_s: float) -> np.ndarray:
    """Motor temperatures after ``dt_arm`` s of arm time: first-order toward ambient plus
    heating with load; injected heating (a fault) runs on wall time ``dt``."""
    b = 1.0 - np.exp(-dt_arm / tau_thermal_s)
    hot = ambient_c + heat_c_per_n * np.abs(tension)
    return temperature + b * (hot - temperature) + heat_rate_c_per_s * dt


def power_up(model) -> tuple[np.ndarray, np.ndarray]:
    """Where the simulated arm powers up: (pose, motor lengths held).

    At θ = 0 with every motor at l = 0, where θ = 0 lies within the joint limits. An arm
    whose zero pose lies outside a joint's limits (an elbow whose range starts at 30°) cannot
    be there: it powers up at the nearest pose within its limits, wires at their holding
    floor, not with the lengths of θ = 0, which would stretch a wire by centimetres against
    the stop (thousands of newtons before the first command).
    """
    theta = np.clip(np.zeros(model.n_joints), model.joint_limits[:, 0],
                    model.joint_limits[:, 1])
    if not theta.any():
        return theta, np.zeros(model.n_muscles)
    floor = np.array([mu.f_floor for mu in model.robot.muscles])
    return theta, model.h_geom(theta) - model.stretch(floor)


class _Solver:
    """Latest-request-wins equilibrium solver thread."""

    def __init__(self, model, theta0: np.ndarray) -> None:
        self._model = model
        self._cond = threading.Condition()
        self._pending: tuple[tuple[str, ...], np.ndarray] | None = None
        self._busy = False
        self._stopped = False
        self._theta = theta0
        self.target = None  # latest Equilibrium
        self.home = False  # someone holds the arm at its home pose (theta = 0)
        self.failure: str | None = None  # a solve that was no rest position (first one)
        self._thread = threading.Thread(target=self._run, name="mock-equilibrium", daemon=True)
        self._thread.start()

    def request(self, modes: tuple[str, ...], values: np.ndarray) -> None:
        with self._cond:
            self._pending = (modes, values)
            self._cond.notify()

    def idle(self) -> bool:
        """No request waiting or being solved: ``target`` answers the latest command."""
        with self._cond:
            return self._pending is None and not self._busy

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._pending is not None or self._stopped)
                if self._stopped:
                    return
                (modes, values), self._pending = self._pending, None
                self._busy = True
            try:
                eq = (self._held_home(modes, values) if self.home else
                      self._model.equilibrium(list(modes), values, theta0=self._theta))
            except Exception as exc:  # noqa: BLE001 - a failed solve keeps the previous target
                log.warning("mock arm: equilibrium failed for %s %s: %s", modes, values, exc)
                eq = None
            failure = None if eq is None else self._failure(eq)
            with self._cond:
                if failure is not None:
                    self.failure = self.failure or failure
                elif eq is not None:
                    self.target, self._theta = eq, np.asarray(eq.theta, float)
                self._busy = False

    def _failure(self, eq) -> str | None:
        """Why a solve is no rest position (None: it is one). A solve that did not converge
        is not where the arm rests, and the arm keeps moving toward the last one that was."""
        if eq.converged and np.isfinite(eq.tension).all():
            return None
        model = self._model
        k = int(np.nanargmax(np.where(np.isfinite(eq.tension), eq.tension, np.inf)))
        return (f"the simulated arm found no rest position under the commands sent (its "
                f"static equilibrium did not converge: residual {eq.residual:.3g} N·m, "
                f"{model.muscles[k]} at {eq.tension[k]:.3g} N): the commands pull its wires "
                "against each other or a joint into its limit. No board or wire failed")

    def _held_home(self, modes, values):
        """The state with the joints held at 0: each wire's own statics, no pose to solve."""
        from types import SimpleNamespace

        model = self._model
        theta = np.zeros(model.n_joints)
        h = model.h_geom(theta)
        values = np.asarray(values, float)
        tension = np.where(np.array(modes) == "tension", np.maximum(values, 0.0),
                           model.tension_from_stretch(h - values))
        return SimpleNamespace(theta=theta, tension=tension, length=h - model.stretch(tension),
                               converged=True, residual=0.0)

    def stop(self) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify()
        self._thread.join(timeout=2.0)


class Plant:
    """True arm state; ``command`` sets motor targets, ``step`` advances time."""

    def __init__(self, model, *, speed: float = 1.0, tau_s: float = 0.075,
                 ambient_c: np.ndarray | float = 25.0, heat_at_f_max_c: float = HEAT_AT_F_MAX_C,
                 tau_thermal_s: float = 30.0) -> None:
        self.model = model
        self.speed, self.tau_s, self.tau_thermal_s = speed, tau_s, tau_thermal_s
        m = model.n_muscles
        self.ambient_c = np.broadcast_to(np.asarray(ambient_c, float), (m,)).copy()
        self.heat_c_per_n = heat_per_newton(model, heat_at_f_max_c)
        self.heat_rate_c_per_s = np.zeros(m)  # injected heating (overheat fault)
        # power-up: motors hold their length, the arm hangs on its elastic elements
        theta, values = power_up(model)
        modes = ("length",) * m
        eq = model.equilibrium(list(modes), values, theta0=theta)
        self.state = PlantState(np.asarray(eq.theta, float), np.asarray(eq.tension, float),
                                np.asarray(eq.length, float), self.ambient_c.copy(),
                                np.zeros(m))
        self._command = (modes, values)
        self._play = FrictionPlay(m)
        self._play.update(self.state.length)
        self._solver = _Solver(model, self.state.theta)
        self._solver.target = eq

    def command(self, modes: tuple[str, ...], values: np.ndarray) -> None:
        """New motor targets (per muscle "length" [m] or "tension" [N]); solved if changed.

        Changes below the resolution that matters (0.02 N, 0.1 µm) are ignored, so targets
        that drift with temperature (a thermal effect) do not keep the solver busy.
        """
        if modes == self._command[0]:
            tol = np.where(np.array(modes) == "tension", 0.02, 1e-7)
            if np.all(np.abs(np.asarray(values) - self._command[1]) <= tol):
                return
        self._command = (modes, np.array(values, float))
        self._solver.request(*self._command)

    def hold_home(self, on: bool = True) -> None:
        """Hold (or let go of) the arm at its home pose, as a person zeroing it would."""
        self._solver.home = on
        self._solver.request(*self._command)

    @property
    def failure(self) -> str | None:
        """Why the simulated arm stopped following its commands (None: it follows them)."""
        return self._solver.failure

    def at_rest(self) -> bool:
        """The arm is on its way to the equilibrium of the commands in force, which it never
        overshoots: a quasi-static arm has no swing to wait for once the solve is done."""
        return self._solver.idle()

    def settled(self, tol: float = 1e-4) -> bool:
        """Solver idle and the state within ``tol`` (m, rad) of its target."""
        target = self._solver.target
        return self._solver.idle() and bool(
            np.all(np.abs(self.state.theta - target.theta) < tol)
            and np.all(np.abs(self.state.length - target.length) < tol))

    def step(self, dt: float) -> PlantState:
        """Advance ``dt`` seconds of wall time (× ``speed`` of arm time).

        The arm moves only toward the equilibrium of the commands in force: while the solver
        still works on newer ones, it holds still (its clock pauses). Moving toward a target
        solved from older commands would make the simulated arm lag its commands by the
        solver's wall time, which grows on a loaded machine; with tendon friction that delay
        closes a loop (friction state → tension target → motion → friction state) that
        oscillates into the tension ceiling. Pausing keeps the arm's response a function of
        arm time alone, the same on a fast or a busy host.
        """
        s, target = self.state, self._solver.target
        dt_arm = dt * self.speed if self._solver.idle() else 0.0
        a = 1.0 - np.exp(-dt_arm / self.tau_s)
        length = s.length + a * (target.length - s.length)
        approach = self._play.update(length)
        temperature = thermal_step(s.temperature, s.tension, self.ambient_c, self.heat_c_per_n,
                                   self.heat_rate_c_per_s, dt_arm, dt, self.tau_thermal_s)
        self.state = replace(s, theta=s.theta + a * (target.theta - s.theta),
                             tension=s.tension + a * (target.tension - s.tension),
                             length=length, temperature=temperature, approach=approach)
        return self.state

    def close(self) -> None:
        self._solver.stop()
