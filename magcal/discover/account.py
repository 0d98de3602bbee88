"""The human-readable account of a discovery: what the gap looked like, what was added.

One line for the initial gap, one per added effect ("Hp residual had an 8.1 nT
peak-to-peak local-time variation peaking at 12 LT; added diurnal (2 harmonics) on
Hp; RMS 4.2 -> 1.1 nT"), one for the stop.
"""

from __future__ import annotations

import numpy as np


def step_interval_text(parameters) -> str:
    """`` (95 %: after <lo>, by <hi> UTC)`` for a step's or a drift break's parameters
    with ``time_ci95`` (ISO times, shown to the minute), else ``""``.

    Examples
    --------
    >>> step_interval_text({"time_ci95": ["2019-12-11T23:02:30+00:00",
    ...                                   "2019-12-12T01:02:30+00:00"]})
    ' (95 %: after 2019-12-11 23:02, by 2019-12-12 01:02 UTC)'
    """
    words = _interval_words(parameters)
    return f" (95 %: {words})" if words else ""


def break_interval_text(parameters) -> str:
    """``, 95 %: after <lo>, by <hi> UTC`` for a drift break's parameters with
    ``time_ci95``, else ``""``: inside the drift's own parentheses.

    Examples
    --------
    >>> break_interval_text({"time_ci95": ["2019-11-12T20:00:00+00:00",
    ...                                    "2019-11-14T03:00:00+00:00"]})
    ', 95 %: after 2019-11-12 20:00, by 2019-11-14 03:00 UTC'
    >>> break_interval_text({})
    ''
    """
    words = _interval_words(parameters)
    return f", 95 %: {words}" if words else ""


def _interval_words(parameters) -> str:
    if "time_ci95" not in parameters:
        return ""
    lo, hi = (t[:16].replace("T", " ") for t in parameters["time_ci95"])
    return f"after {lo}, by {hi} UTC"


def _comps(components) -> str:
    return ", ".join(components)


def _symptom(fe) -> str:
    """What the residual before an effect showed, in the terms of that effect."""
    gap = fe.gap_before or {}
    by = gap.get("by_component", {})
    name = fe.name
    comps = [c for c in fe.components if c in by] or list(by)
    parts = []
    if name == "diurnal":
        for c in comps:
            e = by[c]
            if "lt_peak_to_peak_nT" in e:
                parts.append(f"{c} residual had a {e['lt_peak_to_peak_nT']:.1f} nT peak-to-peak "
                             f"local-time variation peaking at {e['lt_peak_h']:.0f} LT")
    elif name == "offset":
        parts = [f"{c} residual had a mean of {by[c]['mean_nT']:+.1f} nT" for c in comps]
    elif name == "drift":
        parts = [f"{c} residual trended by {by[c].get('trend_nT_per_day', np.nan):+.2f} nT/day"
                 for c in comps]
    elif name in ("temperature", "activity"):
        keys = ("temperature",) if name == "temperature" else ("kp", "dst")
        for c in comps:
            corr = by[c].get("corr", {})
            txt = ", ".join(f"r = {corr[k]:+.2f} with {k}" for k in keys if k in corr
                            and np.isfinite(corr[k]))
            if txt:
                parts.append(f"{c} residual correlated with the covariate ({txt})")
    elif name == "scale":
        parts = [f"{c} residual followed the model field ({100 * by[c]['scale_explained']:.0f}% "
                 "of its variance)" for c in comps if np.isfinite(by[c].get("scale_explained",
                                                                            np.nan))]
    elif name == "rotation" and "rotation_explained" in gap:
        parts = [f"the residual followed w x B_model ({100 * gap['rotation_explained']:.0f}% of "
                 "its variance)"]
    elif name == "step" and "largest_step" in gap:
        st = gap["largest_step"]
        sizes = ", ".join(f"{c} {st['size_nT'][c]:+.1f} nT" for c in comps)
        parts = [f"the residual jumped at {st['time']} ({sizes})"]
    elif name in ("periodic", "spin_tone"):
        derived = fe.parameters.get("derived", {})
        label = (f"a {fe.effect.period_s / 3600:.2f} h tone" if name == "periodic"
                 else "a tone at the spin frequency")
        amps = ", ".join(f"{c} {list(v.values())[0]:.2f} nT" for c, v in derived.items())
        parts = [f"the residual carried {label} ({amps})"]
    return "; ".join(parts) if parts else f"{_comps(comps)} residual"


def _what(fe) -> str:
    p = fe.parameters
    name = fe.name
    if name == "diurnal":
        return f"diurnal ({p['harmonics']} harmonic{'s' if p['harmonics'] > 1 else ''})"
    if name == "periodic":
        return f"periodic ({p['period_h']:.2f} h)"
    if name == "step":
        return f"step at {p['time']}{step_interval_text(p)}"
    if name == "drift" and "break_time" in p:
        return f"drift (rate change at {p['break_time']}{break_interval_text(p)})"
    if name == "rotation":
        angles = ", ".join(f"{v:+.2f}" for v in p["angles_deg"].values())
        return f"rotation ({angles} deg)"
    if name == "activity":
        return f"activity ({', '.join(p['indices'])})"
    return name


def covariate_lines(result) -> list[str]:
    """What the discovery did with its covariates, one sentence each: the samples left
    out where a used covariate is unknown, the covariates not used (with the reason) and
    the values taken as missing for being outside their physical range. The account
    and the chain's warnings both say them.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> r = SimpleNamespace(screened={"samples": 0, "covariate_unknown": 120},
    ...                     covariates={"dst": {"used": False, "reason": "no valid value"}})
    >>> for line in covariate_lines(r):
    ...     print(line)
    left out 120 sample(s) where a covariate is unknown (outside its span or in a hole)
    covariate dst not used: no valid value
    """
    out = []
    if result.screened.get("covariate_unknown"):
        out.append(f"left out {result.screened['covariate_unknown']} sample(s) where a "
                   "covariate is unknown (outside its span or in a hole)")
    for name, cov in (getattr(result, "covariates", None) or {}).items():
        if not cov.get("used"):
            out.append(f"covariate {name} not used: {cov.get('reason')}")
        elif cov.get("out_of_range"):
            out.append(f"covariate {name}: {cov['out_of_range']} value(s) outside its "
                       "physical range taken as missing")
    return out


def account_lines(result) -> list[str]:
    """Lines of the account of a :class:`~magcal.discover.loop.DiscoveryResult`."""
    g0 = result.gap_initial
    by = g0.get("by_component", {})
    per = ", ".join(f"{c} {by[c]['rms_nT']:.2f}" for c in result.components if c in by)
    lines = [f"gap: RMS {g0['rms_nT']:.2f} nT over all components ({per} nT)"]
    left_out = result.screened
    if left_out.get("samples"):
        by = left_out.get("by_test") or {"spike": left_out["samples"]}
        if by.get("spike"):
            lines.append(f"left out {by['spike']} spike sample(s) of measured - model "
                         f"before the fit")
        other = {k: n for k, n in by.items() if n and k != "spike"}
        if other:
            what = ", ".join(f"{k.replace('_', ' ')} {n}" for k, n in other.items())
            lines.append(f"left out {sum(other.values())} more bad sample(s) before the fit "
                         f"({what})")
        lines[-1] += f" (the first left out at {left_out['first']})"
    if left_out.get("no_common_time"):
        n = left_out["no_common_time"]
        lines.append(f"left out {n['measured']} measured and {n['model']} model row(s) at times "
                     "the other file lacks")
    lines += covariate_lines(result)
    unused = getattr(result, "columns_not_used", None) or {}
    for where in ("measured", "model"):
        if unused.get(where):
            lines.append(f"{where} column(s) {', '.join(unused[where])} not in the other file: "
                         "not used")
    if unused.get("all_missing"):
        lines.append(f"component(s) {', '.join(unused['all_missing'])} without any value")
    for fe in result.effects:
        # a slow term (drift) can be highly significant against the day-to-day scatter
        # while the RMS, dominated by fast variability, barely moves: show the change
        nd = 2 if abs(fe.rms_before_nT - fe.rms_after_nT) >= 0.005 else 4
        line = (f"{_symptom(fe)}; added {_what(fe)} on {_comps(fe.components)}; "
                f"RMS {fe.rms_before_nT:.{nd}f} -> {fe.rms_after_nT:.{nd}f} nT "
                f"(z = {fe.evidence['z']:.1f})")
        amb = fe.evidence.get("ambiguous_with") or []
        if amb:
            line += (f"; ambiguous: {' and '.join(amb)} fit the data as well "
                     f"(confounded, the data cannot tell them apart)")
        told = fe.evidence.get("preferred_over") or {}
        if told:
            line += "; preferred over " + ", ".join(
                f"{k} (z = {v['z_vs_winner']:.1f})" for k, v in told.items())
        lines.append(line)
    for r in result.rounds:
        for d in r.get("dropped", ()):
            lines.append(f"dropped {d['name']} on {_comps(d['components'])} in round "
                         f"{r['round']}: {d['reason']}")
        for d in r.get("retracted", ()):
            lines.append(f"retracted {d['name']} at {d['time']} on {_comps(d['components'])}: "
                         f"z = {d['z_joint']:.1f} in the final joint fit, needs "
                         f"{d['z_needed']:.1f} ({d['reason']})")
    said = set()
    for r in result.rounds:
        # a degenerate candidate stays so in every later round: said once, at the first
        for d in r.get("skipped", ()):
            key = (d["name"], tuple(d["components"]))
            if key not in said:
                said.add(key)
                lines.append(f"skipped {d['name']} on {_comps(d['components'])} from round "
                             f"{r['round']}: {d['reason']}")
    lines.append(f"final gap: RMS {result.gap_final['rms_nT']:.2f} nT; "
                 f"stopped: {result.stopped_because}")
    return lines
