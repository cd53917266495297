"""A trained body schema on disk, and the numpy API to use it.

A model directory holds ``model.safetensors`` (the weights, float32) and ``model.json``
(scaling, robot, joints, muscles, map, losses, α, metrics, data sha256, epochs, seed).
Loading reads safetensors and JSON only — never pickle — so a model file from someone
else cannot run code.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.numpy import load_file, save

from pimbs_learn.data import LearnError
from pimbs_learn.domain import Domain
from pimbs_learn.graph import MLP, SERIES_ELASTIC, STRUCTURES, SchemaGraph
from pimbs_learn.model import PARAM_NAMES, Params, Scaling
from pimbs_learn.prior import KEYS as PRIOR_KEYS
from pimbs_learn.prior import PREFIX as PRIOR_PREFIX
from pimbs_learn.run import TrainResult
from pimbs_recording.atomic import write_bytes_atomic, write_text_atomic

WEIGHTS, META = "model.safetensors", "model.json"
FORMAT = "pimbs-body-schema"
FORMAT_VERSION = 1


def model_meta(result: TrainResult) -> dict[str, Any]:
    """The JSON description of a trained model (everything but the weights)."""
    run = result.run
    w = result.params
    return {
        "format": FORMAT, "format_version": FORMAT_VERSION,
        "robot": run.train.robot, "joints": list(run.train.joints),
        "muscles": list(run.train.muscles), "map": run.map_name,
        "inputs": "theta" if not run.atl else "theta+tension",
        "structure": run.structure,
        "prior": ({"kind": "geometric", "robot": run.prior_robot,
                   "rule": "length = h_geom(theta) + learned; G = G_geom + learned"}
                  if run.prior is not None else None),
        "architecture": {"layers": [int(w["w1"].shape[1]), int(w["w1"].shape[0]),
                                    int(w["w2"].shape[0]), int(w["w3"].shape[0])],
                         "activation": "tanh after layers 1 and 2"},
        "scaling": result.scaling.to_json(),
        "domain": Domain.from_samples(run.train.theta,
                                      run.train.tension if run.atl else None).to_json(),
        "loss": run.loss.name, "alpha": run.loss.alpha,
        "data": {"path": run.train.path, "sha256": run.train.sha256},
        "eval_data": {"path": run.eval.path, "sha256": run.eval.sha256},
        "epochs": result.epochs, "seed": run.seed,
        "metrics": result.metrics(),
    }


def save_model(result: TrainResult, out_dir: str | Path, extra: dict[str, Any] | None = None
               ) -> Path:
    """Write the selected weights and their description to ``out_dir``."""
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    # each file whole or not at all: a full disk must not leave a truncated model
    write_bytes_atomic(d / WEIGHTS, save({k: _stored(k, v) for k, v in result.params.items()}))
    meta = {**model_meta(result), **(extra or {})}
    write_text_atomic(d / META, json.dumps(meta, indent=2) + "\n")
    return d


def _stored(name: str, v: np.ndarray) -> np.ndarray:
    """Network weights as float32; the geometric prior's constants exactly (float64, int64)."""
    if name.startswith(PRIOR_PREFIX):
        return np.ascontiguousarray(v, dtype=np.int64 if v.dtype.kind in "iu" else np.float64)
    return np.ascontiguousarray(v, dtype=np.float32)


def _tensor(v: np.ndarray) -> torch.Tensor:
    """float64 for arithmetic, int64 for the prior's index arrays."""
    return torch.from_numpy(np.ascontiguousarray(
        v, dtype=np.int64 if v.dtype.kind in "iu" else np.float64))


def schema_from_result(result: TrainResult) -> BodySchema:
    """The in-memory model of a training result (as if saved and loaded)."""
    return BodySchema({k: _tensor(v) for k, v in result.params.items()}, model_meta(result))


class BodySchema:
    """A loaded body schema: batched numpy in, numpy out (float64), physical units.

    theta (N,) or (B, N) rad; f (M,) or (B, M) N — required for an ATL-Map, ignored by an
    AL-Map's length/jacobian (but needed by ``torque``). Evaluates through
    :class:`~pimbs_learn.graph.SchemaGraph`, the same arithmetic that is exported.
    """

    def __init__(self, params: Params, meta: dict[str, Any]) -> None:
        self.meta = meta
        self.joints: list[str] = list(meta["joints"])
        self.muscles: list[str] = list(meta["muscles"])
        self.atl: bool = meta["map"] == "atl"
        self.structure: str = meta.get("structure", MLP)
        self.scaling = Scaling.from_json(meta["scaling"])
        self.domain = Domain.from_meta(meta)  # training ranges: where it is not extrapolating
        self.graph = SchemaGraph(params, meta).eval()

    @property
    def n_joints(self) -> int:
        return len(self.joints)

    @property
    def n_muscles(self) -> int:
        return len(self.muscles)

    def _evaluate(self, theta: Any, f: Any) -> tuple[bool, np.ndarray, np.ndarray]:
        th = np.asarray(theta, dtype=np.float64)
        single = th.ndim == 1
        th = np.atleast_2d(th)
        if th.shape[-1] != self.n_joints or th.ndim != 2:
            raise LearnError(f"theta must have shape (N,) or (B, N) with N = {self.n_joints}, "
                             f"got {np.shape(theta)}")
        if f is None:
            if self.atl:
                raise LearnError("this is an ATL-Map body schema: pass the tensions f too")
            ft = np.zeros((th.shape[0], self.n_muscles))
        else:
            ft = np.atleast_2d(np.asarray(f, dtype=np.float64))
            if ft.shape != (th.shape[0], self.n_muscles):
                raise LearnError(f"f must have shape (M,) or (B, M) with M = {self.n_muscles} "
                                 f"and the same B as theta, got {np.shape(f)}")
        with torch.no_grad():
            length, g = self.graph(torch.from_numpy(th), torch.from_numpy(ft))
        return single, length.numpy(), g.numpy()

    def length(self, theta: Any, f: Any = None) -> np.ndarray:
        """Predicted muscle lengths l = h(θ[, f]), (M,) or (B, M), m."""
        single, out, _ = self._evaluate(theta, f)
        return out[0] if single else out

    def jacobian(self, theta: Any, f: Any = None) -> np.ndarray:
        """Muscle Jacobian G = ∂h/∂θ, (M, N) or (B, M, N), m/rad."""
        single, _, g = self._evaluate(theta, f)
        return g[0] if single else g

    def length_and_jacobian(self, theta: Any, f: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """(l, G) from one evaluation: the graph computes both anyway, so an estimator that
        needs both pays once."""
        single, out, g = self._evaluate(theta, f)
        return (out[0], g[0]) if single else (out, g)

    def torque(self, theta: Any, f: Any) -> np.ndarray:
        """Joint torque the muscles produce, −Gᵀf, (N,) or (B, N), N·m."""
        if f is None:
            raise LearnError("torque needs the tensions f")
        g = self.jacobian(theta, f)
        return -np.einsum("...mn,...m->...n", g, np.asarray(f, dtype=np.float64))


def load_body_schema(model_dir: str | Path) -> BodySchema:
    """Load a model directory written by :func:`save_model` (safetensors + JSON only)."""
    d = Path(model_dir)
    for name in (WEIGHTS, META):
        if not (d / name).is_file():
            raise LearnError(f"{d}: not a body-schema model directory (missing {name})")
    try:
        meta = json.loads((d / META).read_text())
    except json.JSONDecodeError as e:
        raise LearnError(f"{d / META}: not valid JSON ({e})") from e
    if meta.get("format") != FORMAT or meta.get("format_version") != FORMAT_VERSION:
        raise LearnError(f"{d / META}: not a {FORMAT} v{FORMAT_VERSION} model file")
    try:
        arrays = load_file(str(d / WEIGHTS))
    except Exception as e:  # safetensors raises its own error types for corrupt files
        raise LearnError(f"{d / WEIGHTS}: cannot read weights ({e})") from e
    structure = meta.get("structure", MLP)  # files before the structure field: the MLP
    if structure not in STRUCTURES:
        raise LearnError(f"{d / META}: unknown structure {structure!r} (this PIMBS reads "
                         f"{', '.join(STRUCTURES)}); update PIMBS")
    names = PARAM_NAMES + (("c",) if structure == SERIES_ELASTIC else ())
    if meta.get("prior"):
        names += tuple(PRIOR_PREFIX + k for k in PRIOR_KEYS)
    missing = [k for k in names if k not in arrays]
    if missing:
        raise LearnError(f"{d / WEIGHTS}: missing tensors {missing}")
    params = {k: _tensor(arrays[k]) for k in names}
    atl_inputs = meta["map"] == "atl" and structure == MLP
    n_in = len(meta["joints"]) + (len(meta["muscles"]) if atl_inputs else 0)
    if params["w1"].shape[1] != n_in or params["w3"].shape[0] != len(meta["muscles"]):
        raise LearnError(f"{d}: weight shapes do not match the joints/muscles in {META}")
    return BodySchema(params, meta)
