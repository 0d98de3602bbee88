"""Plots of the offset stage: residual vs local time per month (paper Fig. 19) and the
offset time series with spreads (Fig. 20). matplotlib is imported only when called."""

from __future__ import annotations

import numpy as np

from magcal.offsets.diagnostics import residual_by_local_time
from magcal.offsets.table import COMPONENTS


def plot_residual_local_time(path, times, diff, lon_deg, selected=None, title=None):
    """Save data minus model vs local time, one curve per month, one panel per component.

    Returns the peak-to-peak per month and component (array (months, 3)).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    months, lt, means, _ = residual_by_local_time(times, diff, lon_deg, selected)
    fig, axes = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
    for j, ax in enumerate(axes):
        for i, m in enumerate(months):
            ax.plot(lt, means[i, :, j], marker=".", label=m)
        ax.set_ylabel(f"{COMPONENTS[j]} data - model (nT)")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("local time at the spacecraft (h)")
    axes[-1].set_xlim(0, 24)
    axes[0].legend(fontsize=7, ncol=4)
    fig.suptitle(title or "Data minus model vs local time (one curve per month)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    with np.errstate(invalid="ignore"):
        return np.nanmax(means, axis=1) - np.nanmin(means, axis=1)


def plot_offsets(path, table, title=None):
    """Save the window offsets per component: error bars are the 1-sigma standard errors
    (``table.se_nT``) and the band the spread of the selected samples; without standard
    errors the error bars are the spread. Level changes found in the record
    (``table.level_changes``) are drawn at their day with their 95 % time interval
    shaded: the windows around one mix both levels (unless the product was split at
    them, ``table.segment``: then no line joins the segments)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
    se = table.se_nT
    has_se = se is not None and bool(np.isfinite(se).any())
    for j, ax in enumerate(axes):
        off = table.offset_nT[:, j]
        if has_se:
            ax.fill_between(table.center, off - table.std_nT[:, j], off + table.std_nT[:, j],
                            alpha=0.2, label="spread (std of selected samples)")
        err = se[:, j] if has_se else table.std_nT[:, j]
        seg = getattr(table, "segment", None)
        seg = np.zeros(len(off), dtype=int) if seg is None else np.asarray(seg)
        for n, lab in enumerate(np.unique(seg)):  # no line across a split at a change
            rows = seg == lab
            ax.errorbar(table.center[rows], off[rows], yerr=err[rows], fmt="o-", capsize=3,
                        color="tab:blue", label=None if n else (
                            "offset, 1-sigma standard error" if has_se else "offset, spread"))
        for k, ch in enumerate(getattr(table, "level_changes", ()) or ()):
            ax.axvspan(ch.time_lo, ch.time_hi, color="tab:red", alpha=0.15)
            ax.axvline(ch.time, color="tab:red", lw=1,
                       label=None if k else "level change found (95 % time interval)")
        ax.set_ylabel(f"{COMPONENTS[j]} offset (nT)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    axes[-1].set_xlabel("window centre (UTC)")
    fig.autofmt_xdate()
    fig.suptitle(title or ("DC offsets per sliding window (error bars: standard errors)"
                           if has_se else "DC offsets per sliding window (error bars: std "
                           "of selected data)"))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
