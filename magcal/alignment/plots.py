"""Figures for the uncertainty report: posterior corner plot, angles by window."""

from __future__ import annotations

import numpy as np

from magcal.alignment.noise import COMPONENTS


def plot_posterior_corner(result, params=("w_Hp", "w_He", "w_Hn"), bins: int = 40, fig=None):
    """Corner-style plot of posterior samples (histograms and pairwise scatter).

    Parameters
    ----------
    result : AlignmentResult
        From :func:`magcal.alignment.posterior.sample_posterior` (has ``samples``).
    params : sequence of str
        Names from ``result.mcmc["sample_names"]``; angles are shown in degrees.
    bins : int
    fig : matplotlib Figure, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    if result.samples is None:
        raise ValueError("result has no posterior samples (use sample_posterior)")
    names = list(result.mcmc["sample_names"])
    idx = [names.index(p) for p in params]
    x = result.samples[:, idx]
    k = len(idx)
    if fig is None:
        fig = plt.figure(figsize=(2.4 * k, 2.4 * k))
    axes = fig.subplots(k, k, squeeze=False)
    labels = [p.replace("w_", "angle ") + (" [deg]" if p.startswith("w_") else "")
              for p in params]
    for i in range(k):
        for j in range(k):
            ax = axes[i, j]
            if j > i:
                ax.set_visible(False)
                continue
            if i == j:
                ax.hist(x[:, i], bins=bins, histtype="step", color="k")
                lo, med, hi = np.percentile(x[:, i], [2.5, 50, 97.5])
                for v in (lo, med, hi):
                    ax.axvline(v, color="C0", lw=0.8, ls="--" if v != med else "-")
                ax.set_yticks([])
            else:
                ax.plot(x[:, j], x[:, i], ",", color="k", alpha=0.3)
            if i == k - 1:
                ax.set_xlabel(labels[j])
            if j == 0 and i > 0:
                ax.set_ylabel(labels[i])
    conv = "converged" if result.converged else "NOT converged"
    fig.suptitle(f"alignment posterior ({conv}, tau = {result.autocorr_steps:.0f} steps)")
    return fig


def plot_angles_by_window(windows, fig=None):
    """Angles per window with 1-std error bars, weighted mean and drift line.

    Parameters
    ----------
    windows : WindowAngles
    fig : matplotlib Figure, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    if fig is None:
        fig = plt.figure(figsize=(8, 6))
    axes = fig.subplots(3, 1, sharex=True)
    centre = windows.center
    days = (centre - centre[0]) / np.timedelta64(1, "D")
    for c, ax in enumerate(axes):
        ax.errorbar(centre, windows.angles_deg[:, c], yerr=windows.std_deg[:, c], fmt="o",
                    color="k", ms=3, capsize=2)
        ax.axhline(windows.mean_deg[c], color="C0", lw=1)
        if np.isfinite(windows.drift_deg_per_day[c]):
            mean_day = np.average(days, weights=1 / windows.std_deg[:, c] ** 2)
            ax.plot(centre, windows.mean_deg[c] + windows.drift_deg_per_day[c]
                    * (days - mean_day), color="C1", lw=1, ls="--")
        ax.set_ylabel(f"{COMPONENTS[c]} [deg]")
        ax.set_title(f"mean {windows.mean_deg[c]:.2f} +/- {windows.mean_std_deg[c]:.2f}, "
                     f"spread {windows.spread_deg[c]:.2f}, chi2/dof "
                     f"{windows.chi2_per_dof[c]:.1f}", fontsize=8)
    fig.autofmt_xdate()
    return fig
