"""`pimbs experiment`: the paper's learning experiments (Tables I–III) with figures."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import click

from pimbs_cli.common import check_output, force_option, progress, user_errors


@click.command("experiment")
@click.option("--epochs", type=click.IntRange(min=1), default=None,
              help="epochs per run [default: 20000, or 300 with --quick]")
@click.option("--seeds", type=click.IntRange(min=1), default=None,
              help="seeds per cell [default: 5, or 2 with --quick]")
@click.option("--tables", default="1,2,3", show_default=True,
              help="which tables to run, e.g. '1,2' or '3'")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=Path("experiment-out"), show_default=True,
              help="directory for the tables, curves and figures")
@click.option("--lr", type=click.FloatRange(min=0, min_open=True), default=1e-3,
              show_default=True, help="Adam learning rate of every run (the paper's 1e-3)")
@click.option("--device", type=click.Choice(["cpu", "cuda"]), default="cpu", show_default=True,
              help="cuda trains all runs of one table cell-row together (stacked weights)")
@click.option("--n-train", "n_train", type=click.IntRange(min=1), multiple=True,
              help="only these N_train columns (repeatable), e.g. --n-train 5")
@click.option("--quick", is_flag=True,
              help="smoke run: 300 epochs, 2 seeds, 200-sample D_eval")
@click.option("--reduced", is_flag=True,
              help="the reduced CPU configuration: hidden layers of 256, 3000 epochs, 5 seeds "
                   "(the default is the paper's: 1000, 20000 epochs; use it with --device cuda)")
@click.option("--threads", type=click.IntRange(min=1), default=None,
              help="CPU threads for torch [default: torch's]; 1 is fastest on a busy machine")
@force_option()
@user_errors
def command(threads: int | None, epochs: int | None, seeds: int | None, tables: str,
            out_dir: Path, lr: float, device: str, n_train: tuple[int, ...],
            quick: bool, reduced: bool, force: bool) -> None:
    """Reproduce Tables I–III: mean ± std of L_eval^best (×1e5) over seeds, the paired change
    of each method against Basic (95 % CI), L_eval curves and the joint-angle /
    muscle-length figure, written to --out. Tables II–III add the new default of
    `pimbs train` (series-elastic, automatic α, lr decaying to 1 %) without and with the
    geometric prior, and Basic with that lr schedule (what the schedule alone does)."""
    import torch
    from rich.console import Console
    from rich.table import Table

    from pimbs_learn.experiment import (
        change_cells,
        output_files,
        paper_tables,
        run_table,
        save_outputs,
        table_cells,
        table_runs,
    )
    from pimbs_learn.model import HIDDEN
    from pimbs_learn.run import TrainOptions

    if threads:
        torch.set_num_threads(threads)
    epochs = epochs or (300 if quick else 3000 if reduced else 20000)
    seeds = seeds or (2 if quick else 5)
    specs = _select(paper_tables(quick), tables, n_train)
    check_output(out_dir, force=True, what="directory")  # its parent must exist
    if out_dir.is_dir():  # results of an earlier run are not replaced silently
        for name in output_files(specs):
            check_output(out_dir / name, force=force, what="result of an earlier experiment")
    console = Console(soft_wrap=True)  # a log gets whole lines (command lines stay whole)
    options = TrainOptions(epochs=epochs, lr=lr, device=device,
                           curve_every=max(epochs // 200, 1), hidden=256 if reduced else HIDDEN)
    options.torch_device()  # refuse cuda without a GPU before simulating anything

    groups = [(spec, table_runs(spec, out_dir / "data", seeds, console.print))
              for spec in specs]
    total = sum(len(items) for _, g in groups for items in g.values()) * epochs
    results = []
    done = 0
    with progress("training", total, "epochs", console=console) as update:
        for spec, g in groups:

            def advance(k: int, key: str = spec.key) -> None:
                nonlocal done
                done += k
                update(done, key)

            results.append(run_table(spec, g, options, stack=device == "cuda",
                                     on_epochs=advance, log=console.log))

    for t in results:
        table = Table(title=f"{t.spec.title} — L_eval^best ×1e5, {seeds} seeds, "
                            f"{epochs} epochs")
        table.add_column("Method")
        for n in t.spec.n_train:
            table.add_column(f"N_train={n}", justify="right")
            table.add_column("vs Basic (95 % CI)", justify="right")
        changes = dict(change_cells(t))
        for lab, cells in table_cells(t):
            ch = changes.get(lab, ["" for _ in cells])
            table.add_row(lab, *(x for (c, b), d in zip(cells, ch, strict=True)
                                 for x in (f"[bold]{c}[/bold]" if b else c, d)))
        console.print(table)
    for f in save_outputs(results, out_dir, options, seeds):
        console.print(f"wrote {f}")


def _select(specs: list, tables: str, n_train: tuple[int, ...]) -> list:
    """The tables and N_train columns asked for; a wrong value is blamed on its option."""
    try:
        wanted = {int(s) for s in tables.split(",") if s.strip()}
    except ValueError as e:
        raise click.BadParameter(f"'{tables}' is not a list like 1,2,3",
                                 param_hint="--tables") from e
    keys = {int(s.key[-1]) for s in specs}
    if not wanted or not wanted <= keys:
        raise click.BadParameter(f"'{tables}': the tables are 1, 2 and 3",
                                 param_hint="--tables")
    specs = [s for s in specs if int(s.key[-1]) in wanted]
    if not n_train:
        return specs
    offered = "; ".join(f"table {s.key[-1]}: {', '.join(map(str, s.n_train))}" for s in specs)
    kept = [replace(s, n_train=tuple(n for n in s.n_train if n in n_train)) for s in specs]
    missing = sorted(set(n_train) - {n for s in kept for n in s.n_train})
    if missing:
        raise click.BadParameter(
            f"{', '.join(map(str, missing))} is not a column of the selected tables "
            f"({offered})", param_hint="--n-train")
    return [s for s in kept if s.n_train]
