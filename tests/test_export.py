"""`pimbs export --onnx`: the graph ONNX Runtime runs is the torch model, G is its derivative."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
from click.testing import CliRunner

from pimbs_cli.main import main
from pimbs_learn import load_body_schema
from tests.schema_models import small_model

DOC = Path(__file__).resolve().parent.parent / "docs" / "onnx-cpp.md"


@pytest.fixture(scope="module", params=["atl", "al"])
def exported(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp(f"export-{request.param}")
    model_dir, _ = small_model(tmp, request.param, epochs=50)
    path = tmp / "schema.onnx"
    res = CliRunner().invoke(main, ["export", str(model_dir), "--onnx", str(path)])
    assert res.exit_code == 0, res.output
    return model_dir, path


def _session(path: Path) -> ort.InferenceSession:
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def _inputs(schema, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    d = schema.domain
    f_range = d.tension if d.tension is not None else np.tile([10.0, 300.0], (4, 1))
    return (rng.uniform(*d.theta.T, (n, schema.n_joints)).astype(np.float32),
            rng.uniform(*f_range.T, (n, schema.n_muscles)).astype(np.float32))


def test_onnx_matches_the_torch_model(exported):
    model_dir, path = exported
    schema, sess = load_body_schema(model_dir), _session(path)
    assert [i.name for i in sess.get_inputs()] == ["theta", "tension"]
    assert [o.name for o in sess.get_outputs()] == ["length", "G"]
    for batch in (1, 13):  # the batch dimension is free
        theta, f = _inputs(schema, batch)
        length, G = sess.run(None, {"theta": theta, "tension": f})
        assert length.shape == (batch, 4) and G.shape == (batch, 4, 2)
        assert length.dtype == np.float32
        want_l = schema.length(theta.astype(float), f.astype(float))
        want_g = schema.jacobian(theta.astype(float), f.astype(float))
        assert np.abs(length - want_l).max() <= 1e-5 * np.abs(want_l).max()
        assert np.abs(G - want_g).max() <= 1e-5 * np.abs(want_g).max()


def test_onnx_G_is_the_derivative_of_its_length(exported):
    _, path = exported
    sess = _session(path)
    schema = load_body_schema(exported[0])
    theta, f = _inputs(schema, 6, seed=1)
    _, G = sess.run(None, {"theta": theta, "tension": f})
    h = 1e-3
    for n in range(theta.shape[1]):
        step = np.zeros_like(theta)
        step[:, n] = h
        up = sess.run(["length"], {"theta": theta + step, "tension": f})[0]
        down = sess.run(["length"], {"theta": theta - step, "tension": f})[0]
        fd = (up.astype(float) - down) / (2 * h)
        assert np.abs(G[:, :, n] - fd).max() <= 2e-3 * np.abs(G).max()


def test_metadata_names_the_columns(exported):
    model_dir, path = exported
    meta = _session(path).get_modelmeta().custom_metadata_map
    schema = load_body_schema(model_dir)
    assert json.loads(meta["pimbs.joints"]) == ["shoulder_pitch", "elbow_pitch"]
    assert json.loads(meta["pimbs.muscles"]) == ["m0", "m1", "m2", "m3"]
    assert meta["pimbs.map"] == schema.meta["map"]
    domain = json.loads(meta["pimbs.domain"])
    np.testing.assert_allclose(domain["theta"], schema.domain.theta)


def test_export_refuses_to_overwrite(exported):
    model_dir, path = exported
    res = CliRunner().invoke(main, ["export", str(model_dir), "--onnx", str(path)])
    assert res.exit_code == 1 and "--force" in res.output
    res = CliRunner().invoke(main, ["export", str(model_dir.parent / "nothing"), "--onnx",
                                    str(path.parent / "x.onnx")])
    assert res.exit_code == 1 and "not a body-schema model directory" in res.output


def _onnxruntime_cpp() -> tuple[str, Path, Path] | None:
    """(compiler, include dir, library) when the C++ example can be built here."""
    cxx = shutil.which("c++") or shutil.which("g++")
    inc = [Path(p) for p in (os.environ.get("ORT_INCLUDE_DIR", ""), "/usr/include",
                             "/usr/local/include", "/usr/include/onnxruntime",
                             "/usr/local/include/onnxruntime") if p]
    inc = [p for p in inc if (p / "onnxruntime_cxx_api.h").is_file()]
    lib = os.environ.get("ORT_LIB")
    if lib is None:  # the Python wheel ships the shared library (but not the headers)
        found = sorted((Path(ort.__file__).parent / "capi").glob("libonnxruntime.so*"))
        lib = str(found[0]) if found else None
    if not (cxx and inc and lib and Path(lib).is_file()):
        return None
    return cxx, inc[0], Path(lib)


def test_cpp_example_from_the_docs(exported, tmp_path):
    found = _onnxruntime_cpp()
    if found is None:
        pytest.skip("no C++ compiler with ONNX Runtime headers (set ORT_INCLUDE_DIR/ORT_LIB)")
    cxx, inc, lib = found
    code = re.search(r"```cpp\n(.*?)```", DOC.read_text(), re.S).group(1)
    src = tmp_path / "schema_demo.cpp"
    src.write_text(code)
    exe = tmp_path / "schema_demo"
    subprocess.run([cxx, "-std=c++17", "-O1", str(src), f"-I{inc}", str(lib),
                    f"-Wl,-rpath,{lib.parent}", "-o", str(exe)], check=True, timeout=300)
    out = subprocess.run([str(exe), str(exported[1])], check=True, capture_output=True,
                         text=True, timeout=60).stdout
    rows = [line.split() for line in out.splitlines() if line.startswith("length ")]
    got = np.array([[float(x) for x in r[2:3] + r[4:]] for r in rows])
    theta = np.full((1, 2), 0.1, np.float32)
    f = np.full((1, 4), 50.0, np.float32)
    length, G = _session(exported[1]).run(None, {"theta": theta, "tension": f})
    np.testing.assert_allclose(got[:, 0], length[0], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(got[:, 1:], G[0], rtol=1e-6, atol=1e-9)
