"""The experiment's figures (matplotlib, Agg backend, PNG): L_eval curves and the
joint-angle / muscle-length comparison of the paper's Fig. "analysis"."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pimbs_learn.losses import REPORT_SCALE

if TYPE_CHECKING:
    from pimbs_learn.tables import TableResult


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig, path: Path, dpi: int) -> Path:
    """Write the figure whole or not at all (a full disk must not leave a truncated PNG
    that looks like a result) and close it."""
    from pimbs_recording.atomic import atomic_file

    try:
        with atomic_file(path) as fh:
            fig.savefig(fh, format="png", dpi=dpi)
    finally:
        pyplot().close(fig)
    return Path(path)


def plot_curves(t: TableResult, path: Path) -> Path:
    """L_eval (×1e5, log scale) against epoch: mean over seeds (line) and min–max over
    seeds (band), per method, one panel per N_train."""
    plt = pyplot()
    ns = t.spec.n_train
    fig, axes = plt.subplots(1, len(ns), figsize=(max(5 * len(ns), 7), 4.3),
                             squeeze=False)
    labels = list(dict.fromkeys(m.label for m in t.spec.methods))
    for ax, n in zip(axes[0], ns, strict=True):
        for lab in labels:
            res = t.results[(lab, n)]
            if not len(res[0].curve_eval):
                continue
            c = np.stack([r.curve_eval for r in res]) * REPORT_SCALE
            (line,) = ax.plot(res[0].curve_epochs, c.mean(0), label=lab, lw=1.2)
            # min–max over seeds: mean − std goes negative on a log axis
            ax.fill_between(res[0].curve_epochs, c.min(0), c.max(0),
                            color=line.get_color(), alpha=0.12, lw=0)
        ax.set_yscale("log")
        ax.set_title(f"N_train = {n}")
        ax.set_xlabel("epoch")
        ax.set_ylabel("L_eval ×1e5 [m²]")
        ax.grid(alpha=0.3)
    # one legend above the panels (inside one, up to 7 methods hide its curves)
    handles, names = axes[0][0].get_legend_handles_labels()
    ncol = min(len(names), 2 * len(ns))  # a single panel is too narrow for 4 columns
    rows = -(-len(names) // ncol)
    # two title lines: on one line a long table title runs off a one-panel figure
    top = 1 - (0.5 + 0.2 * rows) / fig.get_figheight()
    fig.suptitle(f"{t.spec.title}\n(line: mean, band: min–max over seeds)", fontsize=10,
                 y=0.995)
    fig.legend(handles, names, loc="upper center", ncol=ncol, fontsize=8,
               frameon=False, bbox_to_anchor=(0.5, 1 - 0.5 / fig.get_figheight()))
    fig.tight_layout(rect=(0, 0, 1, top))
    return save_png(fig, path, dpi=120)


def plot_joint_length(t: TableResult, n: int, path: Path, seed_index: int = 0,
                      points: int = 101) -> Path:
    """Muscle length against each joint angle (the others at 0): the geometric model the
    data came from (solid) and each method's trained model (dashed), for one seed.

    For an AL-Map the model's length at θ is h_geom(θ) − Δn(f(θ)) with f from the QP with
    f_min = 0, i.e. exactly what the simulated data hold.
    """
    from pimbs_arm.model import ArmModel
    from pimbs_learn.io import schema_from_result

    plt = pyplot()
    arm = ArmModel.load(t.spec.robot)
    labels = list(dict.fromkeys(m.label for m in t.spec.methods))
    nj = arm.n_joints
    fig, axes = plt.subplots(len(labels), nj, figsize=(5 * nj, 3 * len(labels)),
                             squeeze=False, sharex="col")
    for j in range(nj):
        lo, hi = arm.joint_range[j]
        theta = np.zeros((points, nj))
        theta[:, j] = np.linspace(lo, hi, points)
        f_min = np.zeros(arm.n_muscles)
        tension = np.stack([arm.tension_distribution(th, f_min) for th in theta])
        truth = arm.length(theta, tension)
        for i, lab in enumerate(labels):
            res = t.results[(lab, n)][seed_index]
            model = schema_from_result(res)
            pred = model.length(theta, tension if model.atl else None)
            ax = axes[i][j]
            for k in range(arm.n_muscles):
                (line,) = ax.plot(theta[:, j], truth[:, k], lw=1.2,
                                  label=f"{arm.muscles[k]} geometric")
                ax.plot(theta[:, j], pred[:, k], "--", color=line.get_color(), lw=1.2,
                        label=f"{arm.muscles[k]} trained")
            tr = res.run.train.theta
            ax.plot(tr[:, j], np.zeros(len(tr)), "k|", ms=8)
            ax.set_title(f"{lab}: moving {arm.joints[j]}", fontsize=9)
            ax.set_ylabel("muscle length [m]")
            ax.grid(alpha=0.3)
        axes[-1][j].set_xlabel(f"{arm.joints[j]} [rad]  (ticks: training θ)")
    # one legend for all panels, above them: inside a panel it hides the curves
    handles, names = axes[0][0].get_legend_handles_labels()
    top = 1 - 0.6 / fig.get_figheight()
    fig.suptitle(f"{t.spec.title}, N_train = {n}, seed {seed_index}: muscle length against "
                 "each joint angle (the other joints at 0)", fontsize=10, y=0.998)
    fig.legend(handles, names, loc="upper center", ncol=arm.n_muscles, fontsize=8,
               frameon=False, bbox_to_anchor=(0.5, top + 0.45 / fig.get_figheight()))
    fig.tight_layout(rect=(0, 0, 1, top))
    return save_png(fig, path, dpi=110)
