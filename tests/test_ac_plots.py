"""Plots render from small scans and series (smoke plus content checks)."""

import numpy as np

from magcal.ac.plots import plot_psd, plot_raw_vs_clean, plot_scan
from magcal.ac.scan import scan_first_order, summarize_scan


def test_plots_render(tmp_path, rng):
    n = 3000
    s = rng.normal(size=(n, 1))
    u = np.array([0.0, 0.6, 0.8])
    amb = 0.05 * rng.normal(size=(n, 3))
    b_i, b_j = amb + 2 * s * u, amb + 5 * s * u
    scan = scan_first_order(b_i, b_j, 100)
    summ = summarize_scan(scan)
    fig = plot_scan(scan, summ)
    assert len(fig.axes) == 3                      # density, colour bar, histogram
    fig.savefig(tmp_path / "scan.png")
    fig = plot_psd(b_i, amb, 1.0, segment_s=512)
    fig.savefig(tmp_path / "psd.png")
    ratio_line = fig.axes[1].lines[0].get_ydata()
    assert np.median(ratio_line) > 100            # disturbance 2 nT rms vs 0.05 nT
    fig = plot_raw_vs_clean(np.arange(n), b_i, amb)
    assert len(fig.axes) == 3
    fig.savefig(tmp_path / "raw.png")
    assert (tmp_path / "scan.png").stat().st_size > 1000
