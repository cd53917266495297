"""An arm PIMBS has never seen, simulated the way another lab's tool might do it.

Independent of `calibration` on purpose (no pinocchio, no via points, no shared effect
code): a planar 3-link arm with 6 muscles whose lengths are closed-form functions of the
joint angles, the paper's sign convention ``l = h(θ) + log1p(f)/K`` (the opposite of
PIMBS'), K = 800, its own noise levels and thermal model. Effects are concealed in their
own implementation. Used to check that the diagnosis works from the recordings alone.

Several effects may be concealed at once (``effects=[(name, size, unit), ...]``), including
a loadcell gain error (``tension_gain``: reads ``(1 + g)·f``) and a routing that differs
from the reference (``routing``: random changes of the moment-arm table, in m), and a
``creep`` that no effect of PIMBS' vocabulary describes (a loadcell reading that grows
linearly over the session, by ``size`` N in all).
"""

from __future__ import annotations

import numpy as np
import quadprog

from pimbs_recording.format import make_meta, write_recording

LINKS = np.array([0.30, 0.25, 0.20])   # m
COM = np.array([0.15, 0.12, 0.10])     # m from each joint
MASS = np.array([2.0, 1.5, 1.0])       # kg
K = 800.0
# h_j(θ) = Σ_k R_jk θ_k + Q_jk (1 − cos θ_k): moment arms R + Q sin θ
R = np.array([[-0.030, 0.000, 0.000], [0.028, 0.000, 0.000], [-0.020, -0.022, 0.000],
              [0.000, 0.025, 0.000], [0.000, -0.015, -0.018], [0.000, 0.010, 0.020]])
Q = np.array([[0.004, 0, 0], [-0.003, 0, 0], [0.002, 0.003, 0], [0, -0.004, 0],
              [0, 0.002, 0.003], [0, -0.002, -0.002]])


def gravity(theta: np.ndarray, mass: np.ndarray = MASS) -> np.ndarray:
    """τ = ∂V/∂θ, V = Σ m g y_com, angles from the horizontal, cumulative."""
    phi = np.cumsum(theta)
    tau = np.zeros(3)
    for ell in range(3):
        for k in range(ell + 1):
            arm = sum(LINKS[i] * np.cos(phi[i]) for i in range(k, ell)) + COM[ell] * np.cos(
                phi[ell])
            tau[k] += mass[ell] * 9.81 * arm
    return tau


def h(theta: np.ndarray, route=0.0) -> np.ndarray:
    return (R + route) @ theta + Q @ (1 - np.cos(theta))


def jac(theta: np.ndarray, route=0.0) -> np.ndarray:
    return R + route + Q * np.sin(theta)[None, :]


def tensions(theta: np.ndarray, tau: np.ndarray, f_min: np.ndarray, route=0.0) -> np.ndarray:
    G = jac(theta, route)
    C = np.hstack([-G, np.eye(6)])
    return quadprog.solve_qp(2 * np.eye(6), np.zeros(6), C, np.concatenate([tau, f_min]),
                             meq=3)[0]


def record(path, n: int, seed: int, effect: str | None = None, size: float = 0.0,
           unit: int = 0, *, effects: tuple = (), routing: float = 0.0) -> None:
    """Write a recording of ``n`` static poses; ``effect``/``effects`` are concealed in it."""
    hidden = ([(effect, size, unit)] if effect else []) + list(effects)
    rng = np.random.default_rng(seed)
    noise = np.random.default_rng(seed + 1000 if hidden or routing else seed + 2000)
    theta_cmd = rng.uniform(-0.6, 0.6, (n, 3))
    f_min = rng.uniform(10, 300, (n, 6))
    route = np.random.default_rng(seed + 77).normal(0.0, routing, R.shape) if routing else 0.0
    mass, k, delta = MASS.copy(), np.full(6, K), np.zeros(3)
    for name, value, where in hidden:
        if name == "link_mass":
            mass[where] *= value
        elif name == "elastic_stiffness":
            k *= value
        elif name == "joint_offset":
            delta[where] += value
    cols = {c: np.zeros((n, w)) for c, w in (("theta", 3), ("tension", 6), ("length", 6),
                                             ("temperature", 6), ("tau_gravity", 3))}
    approach = np.zeros((n, 6), dtype=np.int8)
    prev, temp = np.zeros(6), np.full(6, 22.0)
    for i in range(n):
        th = theta_cmd[i] - delta
        f = tensions(th, gravity(th, mass), f_min[i], route)
        length = h(th, route) + np.log1p(f) / k
        a = np.sign(np.round((length - prev) / 5e-5)).astype(np.int8)
        prev = length
        temp = 22.0 + (temp - 22.0) * 0.97 + 0.03 * 0.08 * f
        reading = f.copy()
        for name, value, where in hidden:  # the loadcell's chain: friction, gain, bias, drift
            if name == "tendon_friction":
                reading = reading * np.exp(-a * value)
            elif name == "tension_gain":
                reading[where] *= 1.0 + value
            elif name == "tension_offset":
                reading[where] += value
            elif name == "thermal_drift":
                reading += value * (temp - 22.0)
            elif name == "creep":  # not in PIMBS' vocabulary: loadcell creeps with time
                reading[where] += value * i / n
        th_meas = theta_cmd[i] + noise.normal(0, 1e-4, 3)
        cols["theta"][i] = th_meas
        cols["tension"][i] = reading + noise.normal(0, 0.5, 6)
        cols["length"][i] = length + noise.normal(0, 1e-5, 6)
        cols["temperature"][i] = temp + noise.normal(0, 0.2, 6)
        cols["tau_gravity"][i] = gravity(th_meas)
        approach[i] = a
    data = {"sample": np.arange(n), "time": 1.78e9 + 2.0 * np.arange(n),
            "theta_command": theta_cmd, "approach": approach, **cols}
    meta = make_meta(["hip", "knee", "ankle"], [f"mus{j}" for j in range(6)], "import",
                     robot="other-lab-3link")
    write_recording(path, data, meta)
