"""Diagnostic plots of AC cleaning (matplotlib, Agg-safe; figures are returned).

- :func:`plot_raw_vs_clean`: raw and cleaned components (the paper's Figs. 4-7);
- :func:`plot_psd`: PSD before and after with their ratio (Fig. 9);
- :func:`plot_scan`: direction density on the 1x1 deg grid and alpha histogram (Fig. 3).
"""

from __future__ import annotations

import numpy as np

from magcal.ac.metrics import psd
from magcal.ac.scan import ScanResult, ScanSummary, direction_density


def _figure(*args, **kw):
    from matplotlib.figure import Figure

    return Figure(*args, **kw)


def plot_raw_vs_clean(t, raw, clean, labels=("x", "y", "z"), title="", subtract_mean=True):
    """Raw (black) and cleaned (red) components in three panels; returns the Figure."""
    fig = _figure(figsize=(10, 7))
    axes = fig.subplots(3, 1, sharex=True)
    for k, ax in enumerate(axes):
        r, c = np.asarray(raw)[:, k], np.asarray(clean)[:, k]
        if subtract_mean:
            r, c = r - np.nanmean(r), c - np.nanmean(c)
        ax.plot(t, r, color="k", lw=0.5, label="raw")
        ax.plot(t, c, color="r", lw=0.5, label="cleaned")
        ax.set_ylabel(f"B{labels[k]} (nT)")
    axes[0].legend(loc="upper right")
    axes[0].set_title(title)
    return fig


def plot_psd(raw, clean, dt_s, segment_s=512.0, title=""):
    """PSD of raw and cleaned data and their ratio (Fig. 9); returns the Figure."""
    f, p_raw = psd(raw, dt_s, segment_s)
    _, p_cln = psd(clean, dt_s, segment_s)
    fig = _figure(figsize=(8, 7))
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    sel = f > 0
    ax1.loglog(f[sel], p_raw[sel], color="k", lw=0.7, label="raw")
    ax1.loglog(f[sel], p_cln[sel], color="r", lw=0.7, label="cleaned")
    ax1.set_ylabel("PSD (nT$^2$/Hz)")
    ax1.legend()
    ax1.set_title(title)
    ax2.semilogx(f[sel], p_raw[sel] / p_cln[sel], color="b", lw=0.7)
    ax2.axhline(1.0, color="grey", lw=0.5)
    ax2.set_ylabel("raw / cleaned")
    ax2.set_xlabel("frequency (Hz)")
    return fig


def plot_scan(scan: ScanResult, summary: ScanSummary, grid_deg: float = 1.0, title=""):
    """Direction density (theta, phi) and alpha histogram of a scan (Fig. 3)."""
    counts, te, pe = direction_density(scan.direction_i[scan.valid], grid_deg)
    fig = _figure(figsize=(8, 8))
    ax1, ax2 = fig.subplots(2, 1)
    mesh = ax1.pcolormesh(pe, te, np.where(counts > 0, counts, np.nan), shading="flat")
    fig.colorbar(mesh, ax=ax1, label="windows per cell")
    ax1.set_xlabel("phi (deg)")
    ax1.set_ylabel("theta (deg)")
    ax1.set_title(title or f"max-variance direction, {scan.window_n}-sample windows")
    a = scan.alpha[scan.valid]
    lo, hi = np.percentile(a, [1, 99])
    bins = np.linspace(lo, hi, 60)
    ax2.hist(a, bins=bins, color="white", edgecolor="k")
    ax2.hist(scan.alpha[summary.selected], bins=bins, color="grey")
    ax2.axvline(summary.alpha, color="r")
    ax2.set_xlabel("alpha")
    ax2.set_ylabel("windows")
    return fig
