"""PNG plots of where the mismatch is and of the fit before and after modelling it.

Written for someone who opens the PNG without the report beside it: every column has a
title, every axis a unit, and values that differ by orders of magnitude (a fit that
improves 500-fold) are drawn on log scales with the numbers printed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pimbs_learn.diagnosis.locate import implied_tension_error
from pimbs_learn.diagnosis.model import evaluate
from pimbs_learn.figures import pyplot, save_png

PLOT_FILES = ("mismatch_by_joint.png", "mismatch_by_factor.png", "fit_before_after.png")
BEFORE, AFTER = "tab:red", "tab:green"


def write_plots(result: dict, internals: dict, out_dir: str | Path) -> list[Path]:
    """Write the three PLOT_FILES into ``out_dir`` (each atomically); returns their paths."""
    out = Path(out_dir)
    out.mkdir(exist_ok=True)
    physics, data = internals["physics"], internals["data"]
    null, final = internals["null"], internals["final"]
    _, r0_tau = evaluate(physics, null, data)
    _, r1_tau = evaluate(physics, final, data) if final.units else (None, None)
    label = _effects_label(result)
    by_joint, by_factor, fit = (out / name for name in PLOT_FILES)
    return [
        _torque_residuals(data.theta, r0_tau, r1_tau, result["joints"], label, by_joint),
        _implied_errors(implied_tension_error(physics, null, data, r0_tau), data,
                        result["muscles"], by_factor),
        _fit_before_after(result["fit"], label, fit),
    ]


def _effects_label(result: dict) -> str:
    """The fitted model's effects: those named, and for what the recording cannot tell
    apart the first explanation, marked as one of several."""
    return " + ".join([e["name"] for e in result["effects"]]
                      + [f"{a['either'][0]['name']} (or {len(a['either']) - 1} other)"
                         for a in result.get("ambiguous", [])])


def _torque_residuals(theta: np.ndarray, before: np.ndarray, after: np.ndarray | None,
                      joints: list[str], label: str, path: Path) -> Path:
    """Torque residual of each joint (rows) against each joint's angle (columns)."""
    plt = pyplot()
    n = len(joints)
    fig, axes = plt.subplots(n, n, figsize=(3.4 * n + 0.4, 2.7 * n + 1.0), squeeze=False,
                             sharex="col", sharey="row")
    for k in range(n):          # residual of joint k
        for i in range(n):      # against angle of joint i
            ax = axes[k, i]
            ax.scatter(theta[:, i], before[:, k], s=5, alpha=0.5, color=BEFORE,
                       label="model alone")
            if after is not None:
                ax.scatter(theta[:, i], after[:, k], s=5, alpha=0.6, color=AFTER,
                           label=f"model + {label}")
            ax.axhline(0, color="k", lw=0.5)
            ax.grid(alpha=0.3)
            if k == 0:
                ax.set_title(f"against {joints[i]}", fontsize=9)
            if k == n - 1:
                ax.set_xlabel(f"{joints[i]} [rad]")
            if i == 0:
                ax.set_ylabel(f"{joints[k]} residual [N·m]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    top = 1 - 0.6 / fig.get_figheight()  # title and legend take the top 0.6 inch
    fig.suptitle("Torque balance residual −Gᵀf − τ across the joint range", fontsize=10,
                 y=0.995)
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, top + 0.35 /
               fig.get_figheight()), fontsize=9, markerscale=3, ncol=2, frameon=False)
    fig.tight_layout(rect=(0, 0, 1, top))
    return save_png(fig, path, dpi=110)


def _implied_errors(err: np.ndarray, data, muscles: list[str], path: Path) -> Path:
    """Per muscle (rows): the tension error that would explain the torque mismatch, by
    approach direction (friction), against temperature (drift) and time (anything slow)."""
    plt = pyplot()
    m = len(muscles)
    fig, axes = plt.subplots(m, 3, figsize=(10.5, 2.1 * m + 1.0), squeeze=False,
                             sharey="row")
    for j in range(m):
        a = data.approach[:, j]
        groups = {"shortening": err[a < 0, j], "still": err[a == 0, j],
                  "lengthening": err[a > 0, j]}
        full = [k for k, g in enumerate(groups.values()) if g.size]  # same x in every row
        axes[j, 0].boxplot([list(groups.values())[k] for k in full], positions=full)
        axes[j, 0].set_xticks(range(3), [f"{name}\n(n={g.size})"
                                          for name, g in groups.items()])
        axes[j, 0].set_xlim(-0.5, 2.5)
        axes[j, 1].scatter(data.temperature[:, j], err[:, j], s=5, alpha=0.5)
        axes[j, 2].scatter(data.time / 60, err[:, j], s=5, alpha=0.5)
        axes[j, 0].set_ylabel(f"{muscles[j]} error [N]")
        for ax in axes[j]:
            ax.axhline(0, color="k", lw=0.5)
            ax.grid(alpha=0.3)
    for ax, title in zip(axes[0], ("by approach direction (last motion)",
                                   "against temperature", "against time"), strict=True):
        ax.set_title(title, fontsize=9)
    axes[-1, 1].set_xlabel("temperature [°C]")
    axes[-1, 2].set_xlabel("time since start [min]")
    fig.suptitle("Implied loadcell error per muscle: the tension error that alone would "
                 "explain the torque mismatch (model without effects)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    return save_png(fig, path, dpi=110)


def _fit_before_after(fit: dict, label: str, path: Path) -> Path:
    """Held-out fit without and with the named effects, log scale, values printed."""
    plt = pyplot()
    panels = (("held-out score\n(whitened MSE, 1 = noise level)", "", fit["before"],
               fit["after"]),
              ("held-out torque RMS", "N·m", fit["torque_rms_Nm"]["before"],
               fit["torque_rms_Nm"]["after"]),
              ("held-out length RMS", "m", fit["length_rms_m"]["before"],
               fit["length_rms_m"]["after"]))
    # one effect per line: several names side by side run into the neighbouring bar's label
    names = ["model alone",
             "model\n+ " + label.replace(" + ", "\n+ ") if label else "no effect\nnamed"]
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.8))
    for ax, (title, unit, before, after) in zip(axes, panels, strict=True):
        vals = np.array([before, after], dtype=float)
        bars = ax.bar(names, vals, color=[BEFORE, AFTER], width=0.6)
        ax.set_yscale("log")
        positive = vals[vals > 0]
        if positive.size:  # room above the bars for their labels
            ax.set_ylim(positive.min() / 3, positive.max() * 8)
        for bar, v in zip(bars, vals, strict=True):
            ax.annotate(f"{v:.3g} {unit}".strip(), (bar.get_x() + bar.get_width() / 2,
                        max(v, ax.get_ylim()[0])), ha="center", va="bottom",
                        xytext=(0, 3), textcoords="offset points", fontsize=9)
        ratio = f"÷ {before / after:.3g}" if after > 0 else ""
        ax.set_title(f"{title}   {ratio}".rstrip(), fontsize=9)
        ax.set_ylabel(f"{unit} (log scale)" if unit else "log scale")
        ax.grid(alpha=0.3, axis="y", which="both")
    fig.suptitle(f"Held-out fit (5-fold CV) before and after modelling "
                 f"{label or 'nothing (no significant missing physics)'}", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    return save_png(fig, path, dpi=110)
