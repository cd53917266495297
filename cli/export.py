"""`pimbs export MODEL --onnx FILE`: a trained body schema for a controller (ONNX Runtime).

One graph, ``(theta [B,N], tension [B,M]) → (length [B,M], G [B,M,N])`` in physical units,
G the exact derivative; see docs/onnx-cpp.md for calling it from C++.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from pimbs_cli.common import check_output, force_option, user_errors


@click.command("export")
@click.argument("model", type=click.Path(file_okay=False, path_type=Path))
@click.option("--onnx", "onnx_path", type=click.Path(dir_okay=False, path_type=Path),
              required=True, help="ONNX file to write")
@force_option()
@user_errors
def command(model: Path, onnx_path: Path, force: bool) -> None:
    """Write MODEL (a `pimbs train --out` directory) as one ONNX graph."""
    check_output(onnx_path, force=force, what="file", option="--onnx")
    import torch

    from pimbs_learn.onnx_export import export_onnx

    torch.set_num_threads(1)
    meta = export_onnx(model, onnx_path)
    joints, muscles = json.loads(meta["pimbs.joints"]), json.loads(meta["pimbs.muscles"])
    click.echo(f"{onnx_path}: inputs theta [B,{len(joints)}] rad ({', '.join(joints)}), "
               f"tension [B,{len(muscles)}] N ({', '.join(muscles)}); outputs length "
               f"[B,{len(muscles)}] m, G [B,{len(muscles)},{len(joints)}] m/rad")
