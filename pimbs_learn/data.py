"""Training samples taken from a recording: the only place pimbs_learn reads recordings.

A :class:`Samples` is plain numpy (θ, f, l, τ) plus the names that make two recordings
comparable. Everything that can go wrong with user input raises :class:`LearnError` with a
message saying what to do, so the CLI can print it instead of a traceback.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np


class LearnError(ValueError):
    """Bad input to learning (file, options, incompatible recordings); message says why."""


@dataclass(frozen=True)
class Samples:
    """Static samples: theta (S,N) rad, tension (S,M) N, length (S,M) m, tau (S,N) N·m.

    tau holds NaN where the recording had no gravity torque and none was computed.
    """

    theta: np.ndarray
    tension: np.ndarray
    length: np.ndarray
    tau: np.ndarray
    joints: tuple[str, ...]
    muscles: tuple[str, ...]
    robot: str | None = None
    sha256: str | None = None
    path: str | None = None

    def __post_init__(self) -> None:
        s, n = self.theta.shape
        m = self.length.shape[1]
        if self.tension.shape != (s, m) or self.length.shape != (s, m) or \
                self.tau.shape != (s, n):
            raise LearnError(f"inconsistent sample arrays: theta {self.theta.shape}, tension "
                             f"{self.tension.shape}, length {self.length.shape}, "
                             f"tau {self.tau.shape}")
        if len(self.joints) != n or len(self.muscles) != m:
            raise LearnError(f"{n} joint / {m} muscle columns but names "
                             f"{list(self.joints)} / {list(self.muscles)}")

    @property
    def n_samples(self) -> int:
        return self.theta.shape[0]

    @property
    def has_tau(self) -> bool:
        return bool(np.isfinite(self.tau).all())

    def take(self, index: np.ndarray) -> Samples:
        return replace(self, theta=self.theta[index], tension=self.tension[index],
                       length=self.length[index], tau=self.tau[index])


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def load_samples(path: str | Path) -> Samples:
    """Read and validate a recording (format v1) into Samples; LearnError if unusable."""
    from pimbs_recording.format import RecordingError, read_recording

    p = Path(path)
    if not p.is_file():
        raise LearnError(f"{p}: no such recording file")
    try:
        rec = read_recording(p)
    except RecordingError as e:
        raise LearnError(str(e)) from e
    if rec.n_rows == 0:
        raise LearnError(f"{p}: the recording has no samples")
    f64 = np.float64
    return Samples(theta=rec.theta.astype(f64), tension=rec.tension.astype(f64),
                   length=rec.length.astype(f64), tau=rec.tau_gravity.astype(f64),
                   joints=tuple(rec.joints), muscles=tuple(rec.muscles), robot=rec.robot,
                   sha256=file_sha256(p), path=str(p))


def load_robot(robot: str, samples: Samples):
    """The robot description ``robot`` (name or path), refused unless it is the recording's
    arm: same joints and muscles in the same order."""
    from pimbs_arm.model import ArmModel

    try:
        arm = ArmModel.load(robot)
    except Exception as e:  # description errors come in several types; all mean "bad robot"
        raise LearnError(f"cannot load robot '{robot}': {e}") from e
    for what, mine, theirs in (("joints", arm.joints, samples.joints),
                               ("muscles", arm.muscles, samples.muscles)):
        if tuple(mine) != tuple(theirs):
            raise LearnError(f"robot '{robot}' has {what} {list(mine)} but "
                             f"{samples.path or 'the recording'} has {list(theirs)}")
    return arm


def fill_gravity(samples: Samples, robot: str | None) -> Samples:
    """Fill missing τ (null tau_gravity) from the robot's joint model.

    L_pinn needs τ for every training sample; a recording from a tool without a dynamics
    model may leave it null, and the robot description can supply it.
    """
    missing = ~np.isfinite(samples.tau).all(axis=1)
    if not missing.any():
        return samples
    if robot is None:
        raise LearnError(
            f"{samples.path or 'recording'}: tau_gravity is null in {int(missing.sum())} of "
            f"{samples.n_samples} rows and the PINN loss needs it; pass --robot NAME|PATH so "
            "it can be computed from the joint model, or train without 'pinn'")
    arm = load_robot(robot, samples)
    tau = samples.tau.copy()
    tau[missing] = np.asarray(arm.gravity_torque(samples.theta[missing]), dtype=np.float64)
    return replace(samples, tau=tau)


def check_compatible(train: Samples, other: Samples) -> None:
    """Refuse to evaluate on a recording of a different body (joint/muscle names, order)."""
    if train.joints != other.joints or train.muscles != other.muscles:
        raise LearnError(
            f"evaluation recording {other.path} does not match the training recording "
            f"{train.path}: joints {list(other.joints)} vs {list(train.joints)}, muscles "
            f"{list(other.muscles)} vs {list(train.muscles)}")


def split(samples: Samples, n_train: int, seed: int, max_eval: int | None = None
          ) -> tuple[Samples, Samples]:
    """Draw n_train samples (seeded, without replacement); the rest is the evaluation set,
    or its first ``max_eval`` rows in the draw's order (to bound the cost of evaluating; the
    training rows are the same either way)."""
    s = samples.n_samples
    if n_train < 1:
        raise LearnError(f"--n-train must be ≥ 1, got {n_train}")
    if n_train >= s:
        raise LearnError(f"--n-train {n_train} leaves no evaluation samples: the recording has "
                         f"{s} rows; use fewer, or give a separate --eval recording")
    perm = np.random.default_rng(seed).permutation(s)
    rest = perm[n_train:] if max_eval is None else perm[n_train:n_train + max_eval]
    return samples.take(np.sort(perm[:n_train])), samples.take(np.sort(rest))
