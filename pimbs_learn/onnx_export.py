"""A trained body schema as one ONNX file, for a controller that does not run Python.

The graph takes ``theta`` [B, N] rad and ``tension`` [B, M] N (float32, B free) and returns
``length`` [B, M] m and ``G`` [B, M, N] m/rad, the exact derivative of ``length`` with
respect to ``theta`` (closed form in the graph, not a finite difference). Scaling is inside,
so a caller passes physical units; the joint and muscle names (the order of the columns),
the robot, the map and the training ranges are in the file's metadata, so a C++ controller
can check that it feeds the columns its schema expects.
"""

from __future__ import annotations

import copy
import hashlib
import io
import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from pimbs_learn.io import WEIGHTS, load_body_schema
from pimbs_recording.atomic import write_bytes_atomic

INPUTS, OUTPUTS = ("theta", "tension"), ("length", "G")
OPSET = 17


def export_onnx(model_dir: str | Path, out: str | Path) -> dict[str, Any]:
    """Write ``out`` (whole or not at all) and return the metadata stored in it."""
    import onnx

    schema = load_body_schema(model_dir)
    graph = _Exported(_graph(schema), schema.atl).eval()
    d = schema.domain
    theta = torch.as_tensor(np.tile(d.theta.mean(axis=1), (2, 1)), dtype=torch.float32)
    f_mid = d.tension.mean(axis=1) if d.tension is not None else np.ones(schema.n_muscles)
    tension = torch.as_tensor(np.tile(f_mid, (2, 1)), dtype=torch.float32)
    out = Path(out)
    buffer = io.BytesIO()
    batch = {0: "batch"}
    with warnings.catch_warnings():
        # torch ≥ 2.9 deprecates the TorchScript exporter in favour of torch.export + onnxscript;
        # it traces this graph exactly (constants folded) and needs no extra dependency, where
        # torch.export refuses the schema's data-dependent scalars.
        warnings.simplefilter("ignore", DeprecationWarning)
        _register_symbolics()
        torch.onnx.export(graph, (theta, tension), buffer, dynamo=False,
                          input_names=list(INPUTS), output_names=list(OUTPUTS),
                          dynamic_axes={k: batch for k in INPUTS + OUTPUTS},
                          opset_version=OPSET, do_constant_folding=True)
    model = onnx.load_from_string(buffer.getvalue())
    meta = metadata(schema, Path(model_dir))
    for key, value in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    model.doc_string = ("PIMBS body schema: length [B,M] m and G = d length / d theta "
                        "[B,M,N] m/rad from theta [B,N] rad and tension [B,M] N")
    onnx.checker.check_model(model)
    write_bytes_atomic(out, model.SerializeToString())
    return meta


def _graph(schema: Any) -> torch.nn.Module:
    """The schema's own evaluation graph in float32 (a copy: the loaded schema keeps its own)."""
    return copy.deepcopy(schema.graph).float()


class _Exported(torch.nn.Module):
    """The schema's graph with one interface for both maps.

    An AL-Map does not use the tensions, and the exporter drops unused inputs; adding
    ``0·tension`` keeps the ``tension`` input, so a controller calls every schema alike.
    """

    def __init__(self, graph: torch.nn.Module, atl: bool) -> None:
        super().__init__()
        self.graph, self.atl = graph, atl

    def forward(self, theta: torch.Tensor, tension: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        length, G = self.graph(theta, tension)
        return (length if self.atl else length + 0.0 * tension), G


def _matrix_transpose(g: Any, x: Any) -> Any:
    """ONNX for ``Tensor.mT`` (swap the last two axes), which the TorchScript exporter lacks."""
    from torch.onnx import symbolic_helper

    perm = list(range(symbolic_helper._get_tensor_rank(x)))
    perm[-2], perm[-1] = perm[-1], perm[-2]
    return g.op("Transpose", x, perm_i=perm)


def _register_symbolics() -> None:
    torch.onnx.register_custom_op_symbolic("aten::mT", _matrix_transpose, OPSET)


def metadata(schema: Any, model_dir: Path) -> dict[str, str]:
    """String metadata (ONNX allows only strings): JSON for the lists."""
    digest = hashlib.sha256((model_dir / WEIGHTS).read_bytes()).hexdigest()
    return {
        "pimbs.format": "pimbs-body-schema-onnx/1",
        "pimbs.joints": json.dumps(schema.joints),
        "pimbs.muscles": json.dumps(schema.muscles),
        "pimbs.robot": str(schema.meta.get("robot")),
        "pimbs.map": schema.meta["map"],
        "pimbs.units": json.dumps({"theta": "rad", "tension": "N", "length": "m",
                                   "G": "m/rad"}),
        "pimbs.domain": json.dumps(schema.domain.to_json()),
        "pimbs.weights_sha256": digest,
    }


def read_metadata(path: str | Path) -> dict[str, str]:
    """The ``pimbs.*`` metadata of an exported file (via onnxruntime, as a user would)."""
    import onnxruntime as ort

    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return dict(sess.get_modelmeta().custom_metadata_map)
