"""Figure of `pimbs estimate`: estimated against measured joint angle, one panel per joint."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pimbs_learn.estimate import DEG, JointAngleReport
from pimbs_learn.figures import pyplot, save_png


def estimate_figure(report: JointAngleReport, measured: np.ndarray, path: Path) -> Path:
    """Scatter of estimate vs measurement (deg), learned and geometric, with the diagonal."""
    plt = pyplot()
    n = len(report.joints)
    fig, axes = plt.subplots(1, n, figsize=(3.6 * n, 3.6), squeeze=False)
    for k, (ax, name) in enumerate(zip(axes[0], report.joints, strict=True)):
        x = measured[:, k] * DEG
        if report.geometric_theta is not None:
            ax.plot(x, report.geometric_theta[:, k] * DEG, "x", color="tab:gray", ms=4,
                    label=f"geometric model ({report.geometric_rms_error_deg[k]:.2g}° rms)")
        ax.plot(x, report.theta[:, k] * DEG, "o", color="tab:blue", ms=3, mfc="none",
                label=f"body schema ({report.rms_error_deg[k]:.2g}° rms)")
        lo, hi = np.nanmin(x), np.nanmax(x)
        ax.plot([lo, hi], [lo, hi], "-", color="k", lw=0.8)
        ax.set_title(name)
        ax.set_xlabel("measured θ [°]")
        ax.set_ylabel("estimated θ [°]")
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    return save_png(fig, path, dpi=110)
