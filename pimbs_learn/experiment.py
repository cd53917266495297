"""The paper's learning experiments (Tables I–III) on simulated recordings.

Table I:  AL-Map,  two-link-4-muscle, N_train ∈ {3, 5, 10}, 4 losses, α = 1e-5.
Table II: ATL-Map, two-link-4-muscle, N_train ∈ {5, 10, 30}, 4 losses, α = 1e-5.
  Both: training rows drawn (per seed) from a training recording; a separate 1000-sample
  recording is D_eval. The paper's simulation is exact, so these use noise 0.
Table III: ATL-Map, left-arm-5dof, 496 samples (standing in for the real arm: sensor noise
  on), N_train ∈ {10, 30} drawn per seed, the rest is D_eval; Basic, Basic+Const,
  Basic+PINN (α = 1e-5) and Basic+Const+PINN with α ∈ {1e-5, 1e-6, 1e-7, 1e-8}.

Data are made with :func:`pimbs_sim.simulate.simulate` exactly as ``pimbs simulate`` does
(the equivalent command lines are printed and saved), and read back through the recording
format, so the experiment exercises the same path as a user's `pimbs train`.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from pimbs_learn.data import Samples, load_samples, split
from pimbs_learn.losses import REPORT_SCALE
from pimbs_learn.paired import paired_change
from pimbs_learn.run import Run, TrainOptions, TrainResult
from pimbs_learn.tables import (
    BASIC_EXP,
    DEFAULT,
    DEFAULT_PRIOR,
    FIVE_DOF,
    PAPER_LOSSES,
    TWO_LINK,
    Method,
    TableResult,
    TableSpec,
)
from pimbs_learn.train import train_runs


def paper_tables(quick: bool = False) -> list[TableSpec]:
    """The three tables; ``quick`` shrinks data sizes for a smoke run, not the structure."""
    paper = tuple(Method(m) for m in PAPER_LOSSES)
    sweep = (Method("basic"), Method("basic+const"), Method("basic+pinn", 1e-5),
             *(Method("basic+const+pinn", a) for a in (1e-5, 1e-6, 1e-7, 1e-8)))
    atl_new = (BASIC_EXP, DEFAULT, DEFAULT_PRIOR)
    ev = 200 if quick else 1000
    return [
        TableSpec("table1", "Table I: AL-Map, 2-DOF 4-muscle simulation", TWO_LINK, False,
                  (3, 5, 10), paper, 100, ev, 0.0),
        TableSpec("table2", "Table II: ATL-Map, 2-DOF 4-muscle simulation", TWO_LINK, True,
                  (5, 10, 30), paper + atl_new, 100, ev, 0.0),
        TableSpec("table3", "Table III: ATL-Map, 5-DOF 10-muscle arm (simulated, noisy), "
                  "α sweep", FIVE_DOF, True, (10, 30), sweep + atl_new, 496, None, 1.0),
    ]


def simulate_recording(path: Path, robot: str, samples: int, atl: bool, seed: int,
                       noise: float) -> str:
    """Write a recording like `pimbs simulate` would; returns that command line."""
    from pimbs_arm.model import ArmModel
    from pimbs_recording.format import write_recording
    from pimbs_sim.simulate import simulate

    map_kind = "atl" if atl else "al"
    cmd = (f"pimbs simulate --robot {robot} --samples {samples} --map {map_kind} "
           f"--seed {seed} --noise {noise:g} --out {path}")
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        data, meta = simulate(ArmModel.load(robot), samples, map_kind, seed=seed, noise=noise)
        write_recording(path, data, meta)
    return cmd


def table_runs(spec: TableSpec, data_dir: Path, seeds: int,
               log: Callable[[str], None]) -> dict[int, list[tuple[Method, Run]]]:
    """Data for one table and its runs, grouped by N_train (runs of one N stack)."""
    m = "atl" if spec.atl else "al"
    base = data_dir / f"{spec.robot}-{m}"
    train_rec = base.with_name(base.name + f"-{spec.pool}.parquet")
    log(simulate_recording(train_rec, spec.robot, spec.pool, spec.atl, 0, spec.noise))
    pool = load_samples(train_rec)
    prior = None
    if any(m.prior for m in spec.methods):
        from pimbs_learn.prior import load_prior
        prior = load_prior(spec.robot, pool.joints, pool.muscles)
    ev: Samples | None = None
    if spec.eval_samples:
        eval_rec = base.with_name(base.name + f"-eval-{spec.eval_samples}.parquet")
        log(simulate_recording(eval_rec, spec.robot, spec.eval_samples, spec.atl, 1000,
                               spec.noise))
        ev = load_samples(eval_rec)
    groups: dict[int, list[tuple[Method, Run]]] = {}
    for n in spec.n_train:
        for seed in range(seeds):
            tr, rest = split(pool, n, seed)
            for method in spec.methods:
                run = Run(tr, ev if ev is not None else rest, method.config(), seed, spec.atl,
                          method.structure, prior if method.prior else None,
                          spec.robot if method.prior else None)
                groups.setdefault(n, []).append((method, run))
    return groups


def run_table(spec: TableSpec, groups: dict[int, list[tuple[Method, Run]]],
              options: TrainOptions, stack: bool,
              on_epochs: Callable[[int], None],
              log: Callable[[str], None] = lambda _: None) -> TableResult:
    """Train every run of a table; ``stack`` trains all runs of one N together.

    Stacking pays on a GPU (one launch per op for all runs). On this CPU it measured ~3x
    slower per run (20 runs' weights no longer fit in cache), so the CLI stacks on cuda only.
    """
    results: dict[tuple[str, int], list[TrainResult]] = {}
    for n, items in groups.items():
        # one structure and learning-rate schedule per stack
        kinds: dict[tuple[str, str], list[tuple[Method, Run]]] = {}
        for it in items:
            kinds.setdefault((it[0].structure, it[0].schedule), []).append(it)
        batches = list(kinds.values()) if stack else [[it] for it in items]
        for batch in batches:
            opts = replace(options, schedule=batch[0][0].schedule)
            done = 0

            def tick(e: int, k: int = len(batch)) -> None:
                nonlocal done
                on_epochs((e - done) * k)
                done = e

            out = train_runs([r for _, r in batch], opts, progress=tick)
            for (method, _), res in zip(batch, out, strict=True):
                results.setdefault((method.label, n), []).append(res)
        log(f"{spec.key} N_train={n}: {len(items)} runs done")
    return TableResult(spec, results)


def table_cells(t: TableResult) -> list[tuple[str, list[tuple[str, bool]]]]:
    """Rows (method label, [(\"mean ± std\", is best mean of its column)]) of a table.

    Three significant digits: well-scaled runs reach L_eval ×1e5 far below 1, where fixed
    decimals would print zeros.
    """
    ns = t.spec.n_train
    labels = list(dict.fromkeys(m.label for m in t.spec.methods))
    best = {n: min(t.cell(lab, n)[0] for lab in labels) for n in ns}
    rows = []
    for lab in labels:
        cells = []
        for n in ns:
            mean, std = t.cell(lab, n)
            cells.append((f"{mean:.3g} ± {std:.2g}", mean == best[n]))
        rows.append((lab, cells))
    return rows


def change_cells(t: TableResult) -> list[tuple[str, list[str]]]:
    """Rows (method label, [paired change of L_eval vs Basic, 95 % CI]) for every method but
    Basic: the same training samples and seeds, so the draw-to-draw spread cancels."""
    labels = list(dict.fromkeys(m.label for m in t.spec.methods))
    base = labels[0]
    rows = []
    for lab in labels[1:]:
        cells = []
        for n in t.spec.n_train:
            b = [r.eval_loss for r in t.results[(base, n)]]
            o = [r.eval_loss for r in t.results[(lab, n)]]
            cells.append(paired_change(np.array(b), np.array(o)).text() if len(b) > 1
                         else "–")
        rows.append((lab, cells))
    return rows


def table_markdown(t: TableResult) -> str:
    """Mean ± std of L_eval^best ×1e5 per method and N_train (best mean in bold), then the
    paired change against Basic with its 95 % interval."""
    ns = t.spec.n_train
    head = "| Method | " + " | ".join(f"N_train={n}" for n in ns) + " |"
    lines = [f"### {t.spec.title}", "", head, "|---|" + "---:|" * len(ns)]
    for lab, cells in table_cells(t):
        lines.append(f"| {lab} | " + " | ".join(f"**{c}**" if b else c for c, b in cells)
                     + " |")
    lines += ["", f"Change of L_eval against {t.spec.methods[0].label} on the same samples "
              "(geometric mean over seeds, 95 % CI):", "", head, "|---|" + "---:|" * len(ns)]
    for lab, cells in change_cells(t):
        lines.append(f"| {lab} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def results_json(tables: list[TableResult], options: TrainOptions, seeds: int) -> dict:
    out: dict = {"epochs": options.epochs, "lr": options.lr, "seeds": seeds,
                 "loss_scale": REPORT_SCALE, "tables": {}}
    for t in tables:
        rows = []
        base = t.spec.methods[0].label
        for (label, n), res in t.results.items():
            mean, std = t.cell(label, n)
            row = {"method": label, "n_train": n, "mean": mean, "std": std,
                   "runs": [r.metrics() for r in res]}
            b = np.array([r.eval_loss for r in t.results[(base, n)]])
            if label != base and len(b) > 1:
                c = paired_change(b, np.array([r.eval_loss for r in res]))
                row["change_vs_basic"] = {"ratio": c.ratio, "ci95": [c.low, c.high],
                                          "mean_ratio": c.mean_ratio}
            rows.append(row)
        out["tables"][t.spec.key] = {"title": t.spec.title, "rows": rows}
    return out


def figure_files(spec: TableSpec) -> list[str]:
    """The figures of one table: its L_eval curves, and for Table I with N_train = 5 the
    joint-angle / muscle-length comparison."""
    names = [f"{spec.key}-curves.png"]
    if spec.key == "table1" and 5 in spec.n_train:
        names.append("table1-joint-length.png")
    return names


def output_files(specs: list[TableSpec]) -> list[str]:
    """Names of the files :func:`save_outputs` writes for these tables (in --out)."""
    return ["tables.md", "results.json", *(n for s in specs for n in figure_files(s))]


def save_outputs(tables: list[TableResult], out_dir: Path, options: TrainOptions,
                 seeds: int) -> list[Path]:
    """tables.md, results.json and the figures, each written atomically; returns them."""
    from pimbs_learn.figures import plot_curves, plot_joint_length
    from pimbs_recording.atomic import write_text_atomic

    out_dir.mkdir(parents=True, exist_ok=True)
    md, js = out_dir / "tables.md", out_dir / "results.json"
    write_text_atomic(md, f"L_eval^best ×1e5 (m²), mean ± std over {seeds} seeds, "
                          f"{options.epochs} epochs\n\n"
                      + "\n".join(table_markdown(t) for t in tables))
    write_text_atomic(js, json.dumps(results_json(tables, options, seeds), indent=1) + "\n")
    files = [md, js]
    for t in tables:
        curves, *joint_length = figure_files(t.spec)
        files.append(plot_curves(t, out_dir / curves))
        if joint_length:
            files.append(plot_joint_length(t, 5, out_dir / joint_length[0]))
    return files
