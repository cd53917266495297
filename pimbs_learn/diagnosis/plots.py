"""PNG plots of where the mismatch is and of the fit before and after modelling it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pimbs_learn.diagnosis.locate import implied_tension_error
from pimbs_learn.diagnosis.model import evaluate


def write_plots(result: dict, internals: dict, out_dir: str | Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    physics, data = internals["physics"], internals["data"]
    null, final = internals["null"], internals["final"]
    joints, muscles = result["joints"], result["muscles"]
    _, r0_tau = evaluate(physics, null, data)
    _, r1_tau = evaluate(physics, final, data)
    paths = []

    # 1. torque residual against each joint angle, before and after
    n = len(joints)
    fig, axes = plt.subplots(n, n, figsize=(3.2 * n, 2.6 * n), squeeze=False)
    for k in range(n):          # residual of joint k
        for i in range(n):      # against angle of joint i
            ax = axes[k, i]
            ax.scatter(data.theta[:, i], r0_tau[:, k], s=4, alpha=0.5, label="model")
            if final.units:
                ax.scatter(data.theta[:, i], r1_tau[:, k], s=4, alpha=0.5,
                           label="with effects")
            ax.axhline(0, color="k", lw=0.5)
            if k == n - 1:
                ax.set_xlabel(f"{joints[i]} [rad]")
            if i == 0:
                ax.set_ylabel(f"τ residual {joints[k]} [N·m]")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("Torque balance −Gᵀf − τ across the joint range")
    fig.tight_layout()
    paths.append(out / "mismatch_by_joint.png")
    fig.savefig(paths[-1], dpi=90)
    plt.close(fig)

    # 2. implied tension error of each muscle against approach, temperature and time
    err = implied_tension_error(physics, null, data, r0_tau)
    m = len(muscles)
    fig, axes = plt.subplots(m, 3, figsize=(10, 2.0 * m + 0.6), squeeze=False)
    for j in range(m):
        a = data.approach[:, j]
        groups = [err[a < 0, j], err[a == 0, j], err[a > 0, j]]
        axes[j, 0].boxplot([g if g.size else np.zeros(1) for g in groups],
                           tick_labels=["shortening", "still", "lengthening"])
        axes[j, 0].set_ylabel(f"{muscles[j]} [N]")
        axes[j, 1].scatter(data.temperature[:, j], err[:, j], s=4, alpha=0.5)
        axes[j, 2].scatter(data.time / 60, err[:, j], s=4, alpha=0.5)
    axes[-1, 1].set_xlabel("temperature [°C]")
    axes[-1, 2].set_xlabel("time [min]")
    fig.suptitle("Implied loadcell error per muscle (model without effects)")
    fig.tight_layout()
    paths.append(out / "mismatch_by_factor.png")
    fig.savefig(paths[-1], dpi=90)
    plt.close(fig)

    # 3. held-out fit before and after
    fit = result["fit"]
    fig, axes = plt.subplots(1, 3, figsize=(9, 3))
    for ax, key, unit in zip(axes, ("before", "torque_rms_Nm", "length_rms_m"),
                             ("whitened MSE", "N·m", "m"), strict=True):
        vals = ([fit["before"], fit["after"]] if key == "before"
                else [fit[key]["before"], fit[key]["after"]])
        ax.bar(["model", "with effects"], vals, color=["tab:red", "tab:green"])
        ax.set_title({"before": "held-out score", "torque_rms_Nm": "held-out torque RMS",
                      "length_rms_m": "held-out length RMS"}[key], fontsize=9)
        ax.set_ylabel(unit)
    names = ", ".join(e["name"] for e in result["effects"]) or "none named"
    fig.suptitle(f"Fit before/after modelling: {names}", fontsize=10)
    fig.tight_layout()
    paths.append(out / "fit_before_after.png")
    fig.savefig(paths[-1], dpi=90)
    plt.close(fig)
    return paths
