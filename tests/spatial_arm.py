"""A second arm PIMBS has never seen, for evaluating learning only (never tuned on).

Independent of `calibration` and of `tests/foreign_arm.py`: a spatial 4-DOF arm (shoulder
yaw about z, shoulder pitch about y, upper-arm roll about x, elbow pitch about y) with 8
muscles, each a straight line from a fixed origin on the torso (or upper arm) to an
insertion on a distal link, so its length is the Euclidean distance — closed form, not
via points through pinocchio. Its elastic law is not the PIMBS one: a power-law
stretch Δn = a·f^0.7 (the paper's + sign), so no learner can get the elastic term for free.
Gravity and the muscle Jacobian come from central differences (this is a data generator,
not a model under test); tensions from the same kind of QP as a lab would use.
"""

from __future__ import annotations

import numpy as np
import quadprog

from pimbs_recording.format import make_meta, write_recording

UPPER, FORE = 0.28, 0.24  # m
MASS = np.array([1.8, 1.2])  # kg, upper arm and forearm (point masses at mid-link)
STRETCH = 2.5e-4  # m per N^0.7
RANGE = 0.5  # rad, every joint
F_MAX = 450.0  # N, tension ceiling
# muscle: (origin frame, origin point, insertion frame, insertion point); frames:
# 0 torso, 1 upper arm (after joints 0-2), 2 forearm (after joint 3)
MUSCLES = [
    (0, (0.04, 0.05, 0.03), 1, (0.0, 0.02, -0.10)),
    (0, (-0.04, 0.05, -0.02), 1, (0.0, 0.02, -0.12)),
    (0, (0.05, -0.04, 0.02), 1, (0.02, -0.02, -0.09)),
    (0, (-0.05, -0.04, -0.03), 1, (-0.02, -0.02, -0.11)),
    (0, (0.0, 0.06, 0.05), 1, (0.02, 0.0, -0.08)),
    (0, (0.0, -0.06, -0.05), 1, (-0.02, 0.0, -0.13)),
    (1, (0.03, 0.0, -0.05), 2, (0.02, 0.0, -0.04)),
    (1, (-0.03, 0.0, -0.06), 2, (-0.02, 0.0, -0.05)),
]


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    i, j = [k for k in range(3) if k != axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def _frames(theta: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """(rotation, origin) of torso, upper arm and forearm; the arm hangs along −z."""
    r1 = _rot(2, theta[0]) @ _rot(1, theta[1]) @ _rot(0, theta[2])
    r2 = r1 @ _rot(1, theta[3])
    return [(np.eye(3), np.zeros(3)), (r1, np.zeros(3)), (r2, r1 @ np.array([0, 0, -UPPER]))]


def h_raw(theta: np.ndarray) -> np.ndarray:
    fr = _frames(theta)
    out = []
    for fa, pa, fb, pb in MUSCLES:
        a = fr[fa][0] @ np.array(pa) + fr[fa][1]
        b = fr[fb][0] @ np.array(pb) + fr[fb][1]
        out.append(np.linalg.norm(b - a))
    return np.array(out)


H0 = h_raw(np.zeros(4))


def h(theta: np.ndarray) -> np.ndarray:
    """Geometric lengths relative to the home pose (h(0) = 0)."""
    return h_raw(theta) - H0


def potential(theta: np.ndarray) -> float:
    fr = _frames(theta)
    z_upper = (fr[1][0] @ np.array([0, 0, -UPPER / 2]))[2]
    z_fore = (fr[2][0] @ np.array([0, 0, -FORE / 2]) + fr[2][1])[2]
    return 9.81 * (MASS[0] * z_upper + MASS[1] * z_fore)


def _diff(fn, theta: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for k in range(4):
        d = np.zeros(4)
        d[k] = eps
        cols.append((np.asarray(fn(theta + d)) - np.asarray(fn(theta - d))) / (2 * eps))
    return np.stack(cols, axis=-1)


def record(path, n: int, seed: int, friction: float = 0.0) -> None:
    """n static samples; with ``friction`` the loadcells read f·exp(−a·μ) (capstan)."""
    rng = np.random.default_rng(seed)
    noise = np.random.default_rng(seed + 7)
    theta_cmd = np.zeros((n, 4))
    cols = {k: np.zeros((n, w)) for k, w in (("theta", 4), ("tension", 8), ("length", 8),
                                             ("temperature", 8), ("tau_gravity", 4))}
    approach = np.zeros((n, 8), dtype=np.int8)
    prev = np.zeros(8)
    for i in range(n):
        while True:  # like a lab, record only poses the muscles can hold under F_MAX
            th = rng.uniform(-RANGE, RANGE, 4)
            g = _diff(h, th)  # (8, 4)
            tau = _diff(potential, th)  # (4,)
            c = np.hstack([-g, np.eye(8)])
            try:
                f = quadprog.solve_qp(2 * np.eye(8), np.zeros(8), c, np.concatenate(
                    [tau, rng.uniform(10, 300, 8)]), meq=4)[0]
            except ValueError:
                continue
            if f.max() <= F_MAX:
                break
        theta_cmd[i] = th
        f = np.maximum(f, 0.0)
        length = h(th) + STRETCH * f ** 0.7
        a = np.sign(np.round((length - prev) / 5e-5)).astype(np.int8)
        prev = length
        reading = f * np.exp(-a * friction)
        cols["theta"][i] = th + noise.normal(0, 1e-4, 4)
        cols["tension"][i] = reading + noise.normal(0, 0.4, 8)
        cols["length"][i] = length + noise.normal(0, 8e-6, 8)
        cols["temperature"][i] = 24.0 + noise.normal(0, 0.2, 8)
        cols["tau_gravity"][i] = _diff(potential, cols["theta"][i])
        approach[i] = a
    data = {"sample": np.arange(n), "time": 1.79e9 + 3.0 * np.arange(n),
            "theta_command": theta_cmd, "approach": approach, **cols}
    meta = make_meta(["yaw", "pitch", "roll", "elbow"], [f"t{j}" for j in range(8)],
                     "import", robot="eval-spatial-4dof")
    write_recording(path, data, meta)
