"""Figures of a discovery: the residual before and after, against time and local time."""

from __future__ import annotations

import numpy as np


def plot_gap(result, path=None, max_points: int = 20000):
    """Plot the residual before and after the added effects.

    One row per component: left, residual against time (before in grey, after in
    black), with each named step that holds the component marked at its time (dashed,
    red) and each drift's rate change at its break (dotted, blue), their 95 % time
    intervals shaded; right, hourly means against local time (when a longitude was
    known).

    Parameters
    ----------
    result : DiscoveryResult
    path : path-like, optional
        Write the figure there (format from the suffix, e.g. ``.png``).
    max_points : int
        Decimate the time panels to at most this many points.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib

    if path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from magcal.discover.gap import local_time_profile
    from magcal.io.atomic import atomic_path

    comps = result.components
    t0 = result.times_s[0]
    t_days = (result.times_s - t0) / 86400.0
    step = max(1, len(t_days) // max_points)
    has_lt = result.local_time_h is not None
    fig, axes = plt.subplots(len(comps), 2 if has_lt else 1, figsize=(11, 2.4 * len(comps)),
                             squeeze=False, constrained_layout=True)
    before, after = result.residual_initial, result.residual_final
    for i, c in enumerate(comps):
        ax = axes[i, 0]
        ax.plot(t_days[::step], before[::step, i], color="0.7", lw=0.5, label="before")
        ax.plot(t_days[::step], after[::step, i], color="k", lw=0.5, label="after")
        for fe in result.effects:
            when = _named_time(fe)
            if when is None or c not in fe.components:
                continue
            label, t_named, colour, style = when
            ax.axvline((t_named - t0) / 86400.0, color=colour, lw=0.8, ls=style, label=label)
            if fe.time_ci95_s is not None:
                lo, hi = ((v - t0) / 86400.0 for v in fe.time_ci95_s)
                ax.axvspan(lo, hi, color=colour, alpha=0.15, lw=0,
                           label=f"{label} time, 95 %")
        ax.set_ylabel(f"{c} residual (nT)")
        if i == len(comps) - 1:
            ax.set_xlabel("days since start")
        if i == 0:
            ax.legend(loc="upper right", fontsize=8)
            ax.set_title("measured - model (before) and - (model + effects) (after)")
        if has_lt:
            ax = axes[i, 1]
            for res, col, lab in ((before, "0.6", "before"), (after, "k", "after")):
                lt, means = local_time_profile(result.local_time_h, res)
                ax.plot(lt, means[:, i], "o-", color=col, ms=3, label=lab)
            ax.axhline(0.0, color="0.8", lw=0.5)
            ax.set_xlim(0, 24)
            ax.set_xticks(np.arange(0, 25, 6))
            if i == 0:
                ax.set_title("hourly mean against local time")
            if i == len(comps) - 1:
                ax.set_xlabel("local time (h)")
    if path is not None:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format=str(path).rsplit(".", 1)[-1], dpi=110)
        plt.close(fig)
    return fig


def _named_time(fe):
    """``(label, time s, colour, line style)`` of a named step or drift break, else None."""
    eff = fe.effect
    if fe.name == "step":
        return "step", eff.t_step_s, "tab:red", "--"
    if fe.name == "drift" and getattr(eff, "t_break_s", None) is not None:
        return "rate change", eff.t_break_s, "tab:blue", ":"
    return None
