"""Training speed, one run on one machine: the reference trainer, Basic and the default,
per epoch and end to end, beside the optimizer's floor.

    .venv/bin/python benchmarks/bench_train.py [--n 5,30,100] [--repeats 3]
        [--epochs 1000] [--processes 3] [--skip-long] [--long-epochs 20000]

What is measured (one torch thread everywhere; ``OMP_NUM_THREADS=1``):

- **floor**: one fused Adam step over the network's tensors (ATL-Map, inputs N+M → H → H →
  M), alone, at the paper's width (1000) and at `pimbs train`'s: what every epoch pays
  whatever its gradient costs. Basic and the default run at `pimbs train`'s width, the
  paper's method (reference and fast) at the paper's.
- **per epoch**, in this process, ms per epoch (median of 50-epoch chunks) at each N of
  ``--n``: *Basic* (``pimbs train --loss basic``), *default* (``pimbs train --alpha 1e-5``:
  Basic+Const+PINN, series-elastic ATL-Map on the description's model) and, at N = 30, the
  *reference* (``pimbs train --reference --structure mlp --no-prior --alpha 1e-5
  --lr-schedule constant``: the paper's method written the straightforward way) and
  *paper, fast* (the same options without ``--reference``: the same work, fast). The
  floor, Basic and the default are measured in turns (``--repeats`` rounds), so a burst of
  other users' work hits all of them alike.
- **end to end**: for each of the four, ``--processes`` ``pimbs train`` processes of
  ``--epochs`` epochs (ATL, N = 30, α = 1e-5, seeds 0, 1, …), start-up, data loading,
  noise estimate, joint-angle report and all, timed from outside; the processes of the
  four alternate. Each process's L_eval (×1e5) is read from its JSON line.
- **optimizer start-up**: in fresh processes (after ``import torch``), the seconds to
  build the optimizer and take its first step: ``torch.optim.Adam(fused=True)``, which
  imports ``torch._dynamo``, against :class:`pimbs_learn.adam.FusedAdam`, and the cost of
  ``import torch._dynamo`` alone.
- **long**: one default ``pimbs train`` of ``--long-epochs`` epochs at N = 30
  (``--skip-long`` skips it).

The data is a seeded ``pimbs simulate`` recording of the built-in two-link arm (ATL-Map,
1000 rows + the training rows; the rows not drawn for training evaluate). ``uptime`` is
printed before and after: on a shared machine the load says how far to trust the numbers.
Prints a markdown table block at the end.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pimbs_learn.adam import FusedAdam  # noqa: E402
from pimbs_learn.losses import LossConfig  # noqa: E402
from pimbs_learn.model import init_params  # noqa: E402
from pimbs_learn.reference import train_reference  # noqa: E402
from pimbs_learn.run import Run, TrainOptions  # noqa: E402
from pimbs_learn.session import prepare_run  # noqa: E402
from pimbs_learn.train import train_runs  # noqa: E402
from pimbs_learn.widths import DEFAULT_HIDDEN, HIDDEN  # noqa: E402

CHUNK = 50  # epochs per timed chunk
ALPHA = 1e-5


class Config(NamedTuple):
    """One trainer measured: how `pimbs train` is asked for it, and what it trains."""

    options: list[str]  # `pimbs train` options
    loss: str
    structure: str
    prior: bool
    schedule: str
    trainer: str  # "fast" or "reference"
    width: int  # hidden layers


# the paper's method at the paper's width, Basic and the default at `pimbs train`'s
_PAPER = ["--structure", "mlp", "--no-prior", "--alpha", str(ALPHA), "--lr-schedule",
          "constant", "--hidden", str(HIDDEN)]
CONFIGS: dict[str, Config] = {
    "reference": Config(["--reference", *_PAPER], "basic+const+pinn", "mlp", False,
                        "constant", "reference", HIDDEN),
    "paper, fast": Config(_PAPER, "basic+const+pinn", "mlp", False, "constant", "fast",
                          HIDDEN),
    "Basic": Config(["--loss", "basic"], "basic", "series-elastic", True, "exp", "fast",
                    DEFAULT_HIDDEN),
    "default": Config(["--alpha", str(ALPHA)], "basic+const+pinn", "series-elastic", True,
                      "exp", "fast", DEFAULT_HIDDEN),
}


def _uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    except OSError:
        return f"load average {os.getloadavg()}"


def _pimbs() -> list[str]:
    exe = shutil.which("pimbs", path=str(Path(sys.executable).parent))
    return [exe] if exe else [sys.executable, "-m", "pimbs_cli.main"]


def chunk_ms(work: Callable[[Callable[[int], None]], None]) -> list[float]:
    """ms per epoch of each chunk of ``CHUNK`` epochs (work calls back with epochs done)."""
    ms: list[float] = []
    last = [time.perf_counter(), 0]

    def done(epoch: int) -> None:
        now = time.perf_counter()
        ms.append((now - last[0]) * 1e3 / (epoch - last[1]))
        last[:] = [now, epoch]

    work(done)
    return ms


def floor_ms(n_in: int, m: int, epochs: int, hidden: int) -> list[float]:
    """One fused Adam step over the tensors of a network this wide, alone, per 'epoch'."""
    params = [t.unsqueeze(0) for t in init_params(n_in, m, seed=0, hidden=hidden).values()]
    grads = [torch.full_like(t, 1e-3) for t in params]
    adam = FusedAdam(params, 1e-3)

    def work(done: Callable[[int], None]) -> None:
        for e in range(epochs):
            adam.step(grads, 1e-3)
            if (e + 1) % CHUNK == 0:
                done(e + 1)

    return chunk_ms(work)


def make_run(data: Path, name: str, n_train: int, seed: int = 0) -> Run:
    c = CONFIGS[name]
    return prepare_run(data, LossConfig.parse(c.loss, ALPHA, "fixed"), atl=True,
                       n_train=n_train, seed=seed, structure=c.structure, prior=c.prior,
                       note=lambda s: None)


def train_ms(run: Run, name: str, epochs: int) -> list[float]:
    """ms per epoch of chunks of a real training run (the trainer `pimbs train` uses)."""
    c = CONFIGS[name]
    opts = TrainOptions(epochs=epochs, schedule=c.schedule, hidden=c.width)
    if c.trainer == "reference":
        return chunk_ms(lambda done: train_reference(run, opts, done, CHUNK))
    return chunk_ms(lambda done: train_runs([run], opts, done, CHUNK))


def per_epoch(data: Path, ns: list[int], epochs: int, repeats: int, ref_epochs: int,
              n_in: int, m: int) -> dict[tuple[str, int], float]:
    """Median ms/epoch of the floor, Basic and default at each N, measured in alternating
    rounds (and of the paper's method, reference and fast, at N = 30)."""
    runs = {(name, n): make_run(data, name, n) for n in ns for name in ("Basic", "default")}
    for (name, _), run in runs.items():  # warm-up: allocator, kernels, first-touch pages
        train_runs([run], TrainOptions(epochs=CHUNK, hidden=CONFIGS[name].width))
    chunks: dict[tuple[str, int], list[float]] = {}
    for _ in range(repeats):
        for width in (HIDDEN, DEFAULT_HIDDEN):
            chunks.setdefault(("floor", width), []).extend(floor_ms(n_in, m, epochs, width))
        for (name, n), run in runs.items():
            chunks.setdefault((name, n), []).extend(train_ms(run, name, epochs))
    if ref_epochs:
        for name in ("reference", "paper, fast"):
            chunks[(name, 30)] = train_ms(make_run(data, name, 30), name, ref_epochs)
    return {k: statistics.median(v) for k, v in chunks.items()}


def pimbs_train(data: Path, name: str, epochs: int, seed: int, n_train: int = 30
                ) -> tuple[float, float]:
    """(wall seconds, L_eval ×1e5) of one `pimbs train` process, start-up included."""
    args = [*_pimbs(), "train", str(data), "--n-train", str(n_train), "--epochs", str(epochs),
            "--seed", str(seed), "--threads", "1", *CONFIGS[name].options]
    t0 = time.perf_counter()
    out = subprocess.run(args, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if out.returncode != 0:
        raise SystemExit(f"{' '.join(args)} failed:\n{out.stderr}")
    return seconds, json.loads(out.stdout.strip().splitlines()[-1])["eval_loss"]


_STARTUP = {
    "import torch._dynamo": "import time; t = time.perf_counter(); import torch._dynamo",
    "torch.optim.Adam(fused=True), build + first step": (
        "ps = [t.requires_grad_(True) for t in init_params(D, M, 0).values()]\n"
        "import time; t = time.perf_counter()\n"
        "o = torch.optim.Adam(ps, lr=1e-3, fused=True)\n"
        "for x in ps: x.grad = torch.ones_like(x)\n"
        "o.step()"),
    "pimbs_learn.adam.FusedAdam, build + first step": (
        "ps = list(init_params(D, M, 0).values())\n"
        "import time; t = time.perf_counter()\n"
        "from pimbs_learn.adam import FusedAdam\n"
        "FusedAdam(ps, 1e-3).step([torch.ones_like(x) for x in ps])"),
}


def optimizer_startup(n_in: int, m: int, repeats: int) -> dict[str, float]:
    """Median seconds of each :data:`_STARTUP` snippet, each in a fresh interpreter that has
    already imported torch, the snippets alternating."""
    head = f"import torch\nfrom pimbs_learn.model import init_params\nD, M = {n_in}, {m}\n"
    tail = "\nprint(time.perf_counter() - t)"
    seconds: dict[str, list[float]] = {k: [] for k in _STARTUP}
    for _ in range(repeats):
        for name, body in _STARTUP.items():
            out = subprocess.run([sys.executable, "-c", head + body + tail], check=True,
                                 capture_output=True, text=True)
            seconds[name].append(float(out.stdout.split()[-1]))
    return {k: statistics.median(v) for k, v in seconds.items()}


def end_to_end(data: Path, epochs: int, processes: int) -> dict[str, tuple[float, list[float]]]:
    """Total wall seconds of ``processes`` runs of each configuration, and their L_eval."""
    total = {name: 0.0 for name in CONFIGS}
    losses: dict[str, list[float]] = {name: [] for name in CONFIGS}
    for seed in range(processes):
        for name in CONFIGS:
            s, loss = pimbs_train(data, name, epochs, seed)
            total[name] += s
            losses[name].append(loss)
            print(f"  {name:9s} seed {seed}: {s:6.1f} s, L_eval {loss:.4g}", flush=True)
    return {name: (total[name], losses[name]) for name in CONFIGS}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", default="5,30,100", help="training-set sizes for per-epoch times")
    ap.add_argument("--repeats", type=int, default=3, help="alternating rounds per epoch")
    ap.add_argument("--epoch-sample", type=int, default=300,
                    help="epochs per measurement of the per-epoch time")
    ap.add_argument("--ref-epochs", type=int, default=200,
                    help="epochs of the reference's per-epoch time (0: skip)")
    ap.add_argument("--epochs", type=int, default=1000, help="epochs per end-to-end process")
    ap.add_argument("--processes", type=int, default=3, help="end-to-end processes per trainer")
    ap.add_argument("--skip-end-to-end", action="store_true")
    ap.add_argument("--long-epochs", type=int, default=20000)
    ap.add_argument("--skip-long", action="store_true", help="skip the long default run")
    a = ap.parse_args()
    torch.set_num_threads(1)
    ns = [int(x) for x in a.n.split(",")]

    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "two-link.parquet"
        subprocess.run([*_pimbs(), "simulate", "--samples", str(1000 + max(ns)), "--seed",
                        "0", "--out", str(data)], check=True, capture_output=True)
        print(f"before: {_uptime()}")
        print(f"torch {torch.__version__}, 1 thread; data: {data.name}, "
              f"{1000 + max(ns)} rows (two-link-4-muscle, ATL)", flush=True)
        run0 = make_run(data, "default", 30)
        n_in, m = run0.scaling().n_inputs, run0.train.length.shape[1]
        startup = optimizer_startup(n_in, m, a.repeats)
        ep = per_epoch(data, ns, a.epoch_sample, a.repeats, a.ref_epochs, n_in, m)
        print(f"per epoch measured: {_uptime()}", flush=True)
        e2e = {} if a.skip_end_to_end else end_to_end(data, a.epochs, a.processes)
        long = None
        if not a.skip_long:
            long = pimbs_train(data, "default", a.long_epochs, seed=0)
        print(f"after: {_uptime()}")

    print()
    for name, sec in startup.items():
        print(f"{name}: {sec:.3f} s (median of {a.repeats} fresh processes)")
    print()
    print("| trainer (width) | " + " | ".join(f"ms/epoch N={n} (× floor)" for n in ns)
          + f" | {a.processes} × `pimbs train` {a.epochs} epochs, N=30 (s) | L_eval ×1e5 |")
    print("|---|" + "---:|" * len(ns) + "---:|---|")
    for width in (HIDDEN, DEFAULT_HIDDEN):
        print(f"| floor: one fused Adam step ({n_in}→{width}→{width}→{m}) | "
              + " | ".join(f"{ep[('floor', width)]:.2f}" for _ in ns) + " | | |")
    for name in CONFIGS:
        cells = []
        floor = ep[("floor", CONFIGS[name].width)]
        for n in ns:
            v = ep.get((name, n))
            cells.append("" if v is None else f"{v:.2f} ({v / floor:.2f}×)")
        total, losses = e2e.get(name, (None, []))
        t = "" if total is None else f"{total:.1f}"
        if total is not None and name != "reference" and "reference" in e2e:
            t += f" (1/{e2e['reference'][0] / total:.1f} of the reference)"
        ls = ", ".join(f"{x:.4g}" for x in losses)
        print(f"| {name} ({CONFIGS[name].width}) | " + " | ".join(cells) + f" | {t} | {ls} |")
    if long is not None:
        print(f"\nOne default `pimbs train --alpha {ALPHA:g}` of {a.long_epochs} epochs at N=30, "
              f"1 thread, start-up included: {long[0]:.1f} s (L_eval {long[1]:.4g}).")


if __name__ == "__main__":
    main()
