"""The split `pimbs train DATA` uses when it is given neither --n-train nor --eval.

A recording alone must train as written in the design (`pimbs train data.parquet`), and a
result is only worth reading if it is measured on rows the model never saw. So a fixed
fraction of the rows is drawn with --seed (the same draw as ``--n-train``) and the rest
evaluates; the rows are named in the output so the split can be reproduced and checked.
"""

from __future__ import annotations

import numpy as np

from pimbs_learn.data import LearnError

#: fraction of a recording's rows that train when no --n-train/--eval is given
TRAIN_FRACTION = 0.8


def default_n_train(n_rows: int, path: str | None = None) -> int:
    """Rows to train on by default: 80 % of the recording, at least one row left to evaluate."""
    if n_rows < 2:
        raise LearnError(f"{path or 'the recording'} has {n_rows} row(s): training needs at "
                         "least 2 (one to train on, one to evaluate); collect more samples "
                         "or give a separate --eval recording")
    return min(n_rows - 1, max(1, int(round(TRAIN_FRACTION * n_rows))))


def eval_rows(n_rows: int, n_train: int, seed: int) -> np.ndarray:
    """The 0-based row numbers that evaluate: the same seeded draw as :func:`data.split`."""
    return np.sort(np.random.default_rng(seed).permutation(n_rows)[n_train:])


def row_ranges(rows: np.ndarray, limit: int = 12) -> str:
    """``3, 7-9, 15, …`` : row numbers as ranges, at most ``limit`` items, for one line."""
    items: list[str] = []
    rows = [int(r) for r in rows]
    i = 0
    while i < len(rows):
        j = i
        while j + 1 < len(rows) and rows[j + 1] == rows[j] + 1:
            j += 1
        items.append(str(rows[i]) if i == j else f"{rows[i]}-{rows[j]}")
        i = j + 1
    if len(items) > limit:
        return ", ".join(items[:limit]) + f", … ({len(items) - limit} more)"
    return ", ".join(items)


def split_note(n_rows: int, n_train: int, seed: int) -> str:
    """The line `pimbs train` prints to say which rows train and which evaluate."""
    ev = eval_rows(n_rows, n_train, seed)
    return (f"no --n-train or --eval: training on {n_train} of {n_rows} rows "
            f"({TRAIN_FRACTION:.0%}, drawn with --seed {seed}); evaluating on the other "
            f"{len(ev)}, rows {row_ranges(ev)} (0-based)")
