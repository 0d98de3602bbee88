"""A picture of what the ELFIN calibration keeps of an injected natural signal.

One panel per zone: the injected signal along its own direction, what the delivered
product returned along it (``calibrated(injected) - calibrated(clean)``), what it
returned across it (the distortion's direction part), and the samples the
calibration left out of its fits, shaded, with the stated bridge error
(``bridge_rms_nT``) as a band about the recovered field. The numbers behind it are
:func:`magcal.missions.elfin.injection.preservation`'s. With both polarities
(:func:`plot_parts`), the signal's own part and the part the same for either
polarity (:func:`magcal.missions.elfin.injection.polarity_parts`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

_COLS = ["bx_gei", "by_gei", "bz_gei"]


def _figure(n: int):
    """pyplot and a figure of ``n`` zone panels stacked (their axes, one per zone)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(n, 1, figsize=(9, 0.6 + 1.9 * n), squeeze=False)
    return plt, fig, axes[:, 0]


def _zone(field: pd.DataFrame, k, state: pd.DataFrame, kind: str):
    """Zone ``k`` of ``field``: its rows (bool), its frame, seconds from its first row
    and the unit vectors (GEI) of the signal's direction there."""
    from magcal.missions.elfin.injection import SIGNALS, directions

    sel = field["zone"].to_numpy() == k
    zf = field[sel]
    t = (zf.index.asi8 - zf.index.asi8[0]) / 1e9
    b = zf[["igrf_x_gei", "igrf_y_gei", "igrf_z_gei"]].to_numpy()
    return sel, zf, t, directions(zf.index, state, b)[SIGNALS[kind][1]]


def _left_and_signal(ax, t, used, left, left_label: str, signal_along) -> None:
    """The samples left out of the fits shaded, and the injected signal along its
    direction."""
    if left.any():
        ax.fill_between(t, 0, 1, where=left, color="0.85", step="mid",
                        transform=ax.get_xaxis_transform(), label=left_label)
    ax.plot(t[used], signal_along[used], color="0.2", lw=2.0, label="injected")


def _zone_head(k, zone_names) -> str:
    return f"zone {k if zone_names is None else list(zone_names)[k]}"


def _label(ax, head: str) -> None:
    ax.set_title(head, fontsize=8, loc="left")
    ax.set_ylabel("nT", fontsize=8)
    ax.tick_params(labelsize=7)


def _save(plt, fig, axes, path, title: str, ncol: int) -> Path:
    """The legend of the first panel below all, the title, and the PNG written."""
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, ncol=ncol, loc="lower center")
    axes[-1].set_xlabel("s from zone start", fontsize=8)
    fig.suptitle(title, fontsize=8)
    fig.tight_layout(rect=(0, 0.35 / (0.6 + 1.9 * len(axes)), 1, 1))
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


def plot_recovered(path: str | Path, clean_day, injected_day, signals: dict, kind: str,
                   state: pd.DataFrame, table: pd.DataFrame | None = None,
                   zone_names=None) -> Path:
    """Injected against recovered, one panel per zone, as PNG (nT, s from zone start).

    Parameters
    ----------
    path : str or Path
        The PNG written.
    clean_day, injected_day : ElfinDay
        The runs :func:`~magcal.missions.elfin.injection.preservation` compares.
    signals : dict
        Zone -> (n, 3) signal in GEI nT, as injected.
    kind : str
        The signal's key in :data:`~magcal.missions.elfin.injection.SIGNALS`.
    state : DataFrame
        The state file (the signal's direction is recomputed from it).
    table : DataFrame, optional
        :func:`~magcal.missions.elfin.injection.preservation` rows of the delivered
        product; their energy kept and distortion head each panel.
    zone_names : sequence, optional
        The day's zone numbers of the zones as calibrated (``zones`` of
        :func:`~magcal.missions.elfin.injection.run_injections`), for the panel titles.
    """
    from magcal.missions.elfin.linear import CREDIT

    fc, fi = clean_day.calibration.field, injected_day.calibration.field
    plt, fig, axes = _figure(len(signals))
    for ax, k in zip(axes, signals):
        sel, zi, t, u = _zone(fi, k, state, kind)
        used = (zi["used"].to_numpy() == 1) & (fc["used"].to_numpy()[sel] == 1)
        dg = np.asarray(signals[k], float)
        rec = zi[_COLS].to_numpy(float) - fc[_COLS].to_numpy(float)[sel]
        along = np.sum(rec * u, axis=1)
        across = np.linalg.norm(rec - along[:, None] * u, axis=1)
        left = used & (zi["fit"].to_numpy() == 0) if "fit" in zi.columns else np.zeros_like(used)
        _left_and_signal(ax, t, used, left, "left out of the fits", np.sum(dg * u, axis=1))
        if "bridge_rms_nT" in zi.columns and left.any():
            e = np.where(left, zi["bridge_rms_nT"].to_numpy(), np.nan)
            ax.fill_between(t, along - e, along + e, color="C1", alpha=0.3, lw=0,
                            label="stated bridge error")
        ax.plot(t[used], along[used], color="C1", lw=0.8, label="recovered, along it")
        ax.plot(t[used], across[used], color="C0", lw=0.6, label="recovered, across it")
        head = _zone_head(k, zone_names)
        if table is not None:
            row = table[table["zone"] == k]
            if len(row):
                head += (f": energy kept {row['energy_kept'].iloc[0]:.0%}, distortion "
                         f"{row['distortion'].iloc[0]:.0%}")
        _label(ax, head)
    return _save(plt, fig, axes, path, f"ELFIN-A: injected {kind} against what the "
                 f"delivered product kept (GEI)\n{CREDIT}", ncol=5)


def plot_parts(path: str | Path, clean_day, plus_day, minus_day, signals: dict, kind: str,
               state: pd.DataFrame, table: pd.DataFrame | None = None,
               zone_names=None) -> Path:
    """The signal's own part and the part the same for either polarity, one panel per
    zone, as PNG (nT, s from zone start).

    Along the signal's direction: the injected signal, the odd part ``(r+ - r-) / 2``
    of what the two polarities brought back (what the product makes of the signal) and
    the even part ``(r+ + r-) / 2`` (the day's own field over the interval the signal
    made the calibration leave out); the samples either run left out of its fits are
    shaded. ``plus_day`` carries ``signals``, ``minus_day`` their negatives; ``table``
    (:func:`~magcal.missions.elfin.injection.polarity_parts` rows of the delivered
    product) heads each panel with its numbers.
    """
    from magcal.missions.elfin.injection import recovered_both
    from magcal.missions.elfin.linear import CREDIT

    fc, fp, fm = (d.calibration.field for d in (clean_day, plus_day, minus_day))
    plt, fig, axes = _figure(len(signals))
    for ax, k in zip(axes, signals):
        sel, zp, t, u = _zone(fp, k, state, kind)
        used, r_plus, r_minus = recovered_both(fc, fp, fm, sel)
        odd = np.sum(0.5 * (r_plus - r_minus) * u, axis=1)
        even = np.sum(0.5 * (r_plus + r_minus) * u, axis=1)
        left = used & ((zp["fit"].to_numpy() == 0) | (fm["fit"].to_numpy()[sel] == 0))
        _left_and_signal(ax, t, used, left, "left out of the fits (either run)",
                         np.sum(np.asarray(signals[k], float) * u, axis=1))
        ax.plot(t[used], odd[used], color="C1", lw=0.9, label="own part (r+ - r-)/2")
        ax.plot(t[used], even[used], color="C2", lw=0.9,
                label="the same for either polarity (r+ + r-)/2")
        head = _zone_head(k, zone_names)
        if table is not None:
            row = table[table["zone"] == k]
            if len(row):
                r = row.iloc[0]
                head += (f": own part kept {r['energy_kept_odd']:.0%}, distortion "
                         f"{r['distortion_odd']:.0%}; the other part {r['even_rms']:.0%} of "
                         "the signal (RMS)")
        _label(ax, head)
    return _save(plt, fig, axes, path, f"ELFIN-A: injected {kind}, both polarities: the "
                 f"signal's own part and the day's (GEI, along the signal)\n{CREDIT}", ncol=4)
