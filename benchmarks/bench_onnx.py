"""Does one evaluation of the exported schema fit a 1 kHz control loop on one CPU core?

Times ``length`` and ``G`` of one pose through ONNX Runtime (1 intra-op and 1 inter-op
thread, sequential execution, inputs bound once as a controller would), and a batch of 100
poses, against the same model in torch (``BodySchema``, float64, 1 thread). The weights do
not change the cost, so by default the model is `pimbs train`'s architecture (hidden 1000)
trained for a few epochs on a simulated recording of ``--robot``; or pass ``--model DIR``.

    nice -n 10 .venv/bin/python benchmarks/bench_onnx.py
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch


def tiny_model(tmp: Path, robot: str) -> Path:
    from pimbs_arm.model import ArmModel
    from pimbs_learn.io import save_model
    from pimbs_learn.losses import LossConfig
    from pimbs_learn.run import TrainOptions
    from pimbs_learn.session import prepare_run
    from pimbs_learn.train import train
    from pimbs_recording.format import write_recording
    from pimbs_sim.simulate import simulate

    data, meta = simulate(ArmModel.load(robot), 40, "atl", seed=1)
    write_recording(tmp / "d.parquet", data, meta)
    run = prepare_run(tmp / "d.parquet", LossConfig.parse("basic", 0.0), n_train=30)
    return save_model(train(run, TrainOptions(epochs=5)), tmp / "model")


def timings(fn, repeat: int) -> np.ndarray:
    for _ in range(min(200, repeat)):
        fn()
    out = np.empty(repeat)
    for k in range(repeat):
        t0 = time.perf_counter()
        fn()
        out[k] = time.perf_counter() - t0
    return out * 1e3


def main() -> None:
    import onnxruntime as ort

    from pimbs_learn import load_body_schema
    from pimbs_learn.onnx_export import export_onnx

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--robot", default="two-link-4-muscle", help="arm of the default model")
    ap.add_argument("--repeat", type=int, default=5000)
    a = ap.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        model = a.model or tiny_model(Path(tmp), a.robot)
        onnx = Path(tmp) / "schema.onnx"
        export_onnx(model, onnx)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        sess = ort.InferenceSession(str(onnx), opts, providers=["CPUExecutionProvider"])
        schema = load_body_schema(model)
        rng = np.random.default_rng(0)
        n, m = schema.n_joints, schema.n_muscles
        rows = []
        for batch in (1, 100):
            theta = rng.uniform(*schema.domain.theta.T, (batch, n)).astype(np.float32)
            f = rng.uniform(20, 300, (batch, m)).astype(np.float32)
            binding = sess.io_binding()
            binding.bind_cpu_input("theta", theta)
            binding.bind_cpu_input("tension", f)
            binding.bind_output("length")
            binding.bind_output("G")
            ort_ms = timings(lambda b=binding: sess.run_with_iobinding(b), a.repeat // batch)
            th64, f64 = theta.astype(float), f.astype(float)
            torch_ms = timings(lambda t=th64, g=f64: (schema.length(t, g), schema.jacobian(t, g)),
                               max(a.repeat // (10 * batch), 20))
            rows.append((batch, ort_ms, torch_ms))
    arch = schema.meta.get("architecture", {}).get("layers")
    print(f"model {model}: layers {arch}, {n} joints, {m} muscles; ONNX Runtime "
          f"{ort.__version__}, 1 thread")
    print("| batch | ONNX Runtime median / p99 [ms] | per pose [µs] "
          "| torch BodySchema median [ms] |")
    print("|---|---|---|---|")
    for batch, o, t in rows:
        print(f"| {batch} | {np.median(o):.3f} / {np.percentile(o, 99):.3f} | "
              f"{1e3 * np.median(o) / batch:.1f} | {np.median(t):.3f} |")


if __name__ == "__main__":
    main()
