"""A small trained body schema on disk, for the tests that use one (estimate, export, collect).

Trained for seconds on a clean simulated recording of the two-link arm (hidden 48): good
enough to be a smooth, injective map, which is all those tests need; accuracy is measured
by the benchmark, not here.
"""

from __future__ import annotations

from pathlib import Path

import torch

from pimbs_arm.model import ArmModel
from pimbs_learn.io import save_model
from pimbs_learn.losses import LossConfig
from pimbs_learn.run import TrainOptions
from pimbs_learn.session import prepare_run
from pimbs_learn.train import train
from pimbs_recording.format import write_recording
from pimbs_sim.simulate import simulate


def simulated_recording(path: Path, n: int = 40, map_kind: str = "atl", seed: int = 1) -> Path:
    data, meta = simulate(ArmModel.load("two-link-4-muscle"), n, map_kind, seed=seed,
                          noise=0.0)
    write_recording(path, data, meta)
    return path


def small_model(tmp: Path, map_kind: str = "atl", epochs: int = 400) -> tuple[Path, Path]:
    """(model directory, its recording) in ``tmp``."""
    torch.set_num_threads(1)
    data = simulated_recording(tmp / f"sim-{map_kind}.parquet", map_kind=map_kind)
    run = prepare_run(data, LossConfig.parse("basic", 0.0), atl=map_kind == "atl",
                      n_train=30, seed=0)
    result = train(run, TrainOptions(epochs=epochs, hidden=48, lr=3e-3))
    return save_model(result, tmp / f"model-{map_kind}"), data
