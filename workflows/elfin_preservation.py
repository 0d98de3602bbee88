"""What the ELFIN-A calibration keeps of natural signals: the preservation table.

Synthetic natural signals (:data:`magcal.missions.elfin.injection.SIGNALS`: east-west
and along-track 200 nT Gaussian pulses of 40 s FWHM, a 300 nT east-west current sheet
rising over 20 s to the zone's end, a 100 nT pulse along B of 90 s FWHM, a 5 nT 2 Hz
wave packet of 10 s) are added to the raw counts of the real day through the inverse of
the clean linear calibration and spin phase, one signal in each chosen zone per run;
the day is calibrated again and ``calibrated(injected) - calibrated(clean)`` in GEI is
compared with the signal for every product of the pipeline
(:func:`magcal.missions.elfin.injection.run_injections`).

The runs of the table, so that each step's share can be read:

* ``held``: the spin phase held at its clean solution, no phase refit and no detection
  (the machinery check: only the per-zone linear fit can absorb, and it takes the zone
  mean);
* ``delivered``: :class:`~magcal.missions.elfin.pipeline.ElfinSettings` defaults, with
  the disturbed intervals located from the counts (:mod:`magcal.missions.elfin.detect`);
  the clean day's flagged share per zone, what the bridge check leaves out and the
  residual on the unflagged samples are printed too;
* ``--settings KEY=VALUE ...``: any other settings (e.g. ``detect_disturbed=false``:
  every step fitted on every sample; ``linear_phase_knot_s=30 refit_knot_s=60``, the
  phase splines of before);
* ``--mask-signal 0.05``: the steps without detection, the samples where the signal
  exceeds 5 % of its peak left out of every fit (``fit_exclude``): what the pipeline
  keeps when the disturbed interval is known from elsewhere;
* ``--both-signs``: every signal also with the opposite polarity; what came back is
  split into the part that follows the signal (odd, ``(r+ - r-) / 2``) and the part
  that is the same for either polarity (even: the day's own field over the interval the
  signal made the calibration leave out, which the clean run gave to a drift)
  (:func:`magcal.missions.elfin.injection.polarity_parts`);
* ``--joined`` (with ``--both-signs``): both polarities calibrated once more with the
  union of their left-out rows given, so that their intervals end at the same places
  (:func:`magcal.missions.elfin.injection.joined_parts`): how much of the odd part's
  distortion is where the detector drew an interval's ends (which depends on the day's
  own field beside the signal) and how much the calibration's own doing;
* ``--mask-injected-only 0.05``: the same samples left out of the injected run's fits
  only, as a detector would that flags exactly the signal and nothing on the clean
  day; its distortion is the calibration's own change when that interval is left out
  (the floor of any detect-and-exclude scheme);
* ``--leave-out 0.05``: no signal injected, the clean day (delivered settings,
  detection on) calibrated again with each pulse's rows above 5 % of its peak left
  out (:func:`magcal.missions.elfin.leave_out.leave_out_effect`): the change of the
  product read against the pulse, per case, next to the delivered run's distortion,
  and the amplitude at which it would be within 10 % (pulses across B only, the
  signals the product keeps by leaving them out).

Before the runs, the share of each signal's energy in its projection on polynomials
in time over the zone (degree 0 the zone mean, up to the gain drift's cubic) is
printed: what a per-zone drift of that degree fitted against the model takes when
nothing else competes (:func:`magcal.missions.elfin.injection.polynomial_share`).

Usage::

    python workflows/elfin_preservation.py [--zones 1,4,7,10] [--signals gauss_ew,...]
                                           [--no-held] [--settings KEY=VALUE ...]
                                           [--mask-signal FRACTION]
                                           [--mask-injected-only FRACTION]
                                           [--centres 0.5,...] [--sign -1] [--scale 1]
                                           [--both-signs]
                                           [--joined] [--leave-out FRACTION]
                                           [--plot DIR]

The README's whole-day sheet numbers (36 placements, with and without level steps)::

    python workflows/elfin_preservation.py --zones all --signals sheet_ew --no-held \
        --centres 0.35,0.5,0.65 --settings level_steps=false

The whole day (12 zones) with ``--both-signs`` takes about a minute per signal and place
on one core (two signals at three places: 343 s; with ``--joined`` 545 s); the default
zones (4) take about a third of that. Reads ``../shared/real-data/elfin/``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
DATA = HERE.parent.parent / "shared" / "real-data" / "elfin"
FGS_FILE = "ela_l1_fgs_20220112_v01.cdf"
STATE_FILE = "ela_l1_state_defn_20220112_v01.cdf"
#: Default zones: two night-side (1, 4), one sunlit dawn (7) and one late pass (10).
ZONES = (1, 4, 7, 10)


def _settings(pairs):
    from magcal.missions.elfin.pipeline import ElfinSettings

    given = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        low = value.strip().lower()
        given[key.strip()] = (low == "true") if low in ("true", "false") else float(value)
    return ElfinSettings.from_mapping(given, where="--settings")


def _print(label, tab, clean) -> None:
    import pandas as pd

    pd.set_option("display.width", 200)
    cols = ["energy_kept", "distortion", "energy_kept_ac", "distortion_ac", "zone_mean_share"]
    both = tab["sign"].nunique() > 1
    keys = ["signal", "product", "sign"] if both else ["signal", "product"]
    print(f"\n== {label}: zone medians (energy_kept: share of the signal's energy kept in "
          "its shape; _ac: zone means removed from both)")
    print(tab.groupby(keys, sort=False)[cols].median().round(3).to_string())
    print(f"\n== {label}: delivered product, per zone")
    last = tab[tab["product"] == tab["product"].iloc[-1]]
    print(last.pivot_table(index=keys[::2], columns="zone", values="energy_kept")
          .round(3).to_string())
    if both:
        _print_parts(label, last)
    from magcal.missions.elfin.injection import TARGET_DISTORTION, TARGET_ENERGY, target_counts

    print(f"\n== {label}: cases meeting the targets (energy kept at least "
          f"{TARGET_ENERGY:.0%}, distortion at most {TARGET_DISTORTION:.0%}): on the whole "
          "signal, each polarity a case; odd_: on the signal's own part, one case per "
          "zone and place")
    print(target_counts(last).to_string(index=False))
    if "bridge_rms_nT" in last.columns:
        b = last.dropna(subset=["error_rms_nT", "bridge_rms_nT"])
        ratio = b["error_rms_nT"] / b["bridge_rms_nT"]
        print(f"\n== {label}: stated bridge error (bridge_rms_nT) against the kept signal's "
              f"error over its left-out samples: {len(b)} of {len(last)} zone-signal cases "
              f"with both; error within the stated one in {(ratio <= 1).mean():.0%}, within "
              f"twice it in {(ratio <= 2).mean():.0%} (ratio median {ratio.median():.2f})")
    med = pd.DataFrame(clean.medians()).T
    print(f"\n== {label}: residual of the clean run (zone medians, nT)")
    print(med[["scalar_rms_nT", "scalar_fast_nT", "scalar_slow_nT", "vector_rms_nT"]]
          .round(2).to_string())
    if "disturbed_detection" in clean.steps:
        from magcal.missions.elfin.joint import score_field

        det = clean.steps["disturbed_detection"]
        print(f"\n== {label}: clean day, share of each zone's used samples flagged "
              "(detect_disturbed; zones numbered in the calibrated order)")
        print(det.pivot(index="pass", columns="zone", values="flagged_share").round(3)
              .to_string())
        if "kept_share" in det.columns:
            last = det[det["pass"] == det["pass"].max()]
            print("left out of the fits after the bridge check (runs that brought back "
                  "more spin tones than slow field are put back): "
                  + ", ".join(f"{v:.3f}" for v in last["kept_share"]))
        f = clean.calibration.field.copy()
        f.loc[f["fit"] == 0, "used"] = 0
        quiet = score_field(f).drop(columns="zone").median()
        print("clean residual on the unflagged samples only (zone medians, nT): "
              + ", ".join(f"{k} {quiet[k]:.2f}" for k in ("scalar_rms_nT", "scalar_fast_nT",
                                                          "vector_rms_nT")))


def _print_parts(label, last) -> None:
    """The delivered product's odd and even parts (``polarity_parts``), zone medians and
    per zone."""
    first = last[last["sign"] == last["sign"].iloc[0]]
    kept = last.pivot_table(index="signal", columns="sign", values="energy_kept",
                            aggfunc="median", sort=False)
    kept.columns = [f"energy_kept (sign {s:+g})" for s in kept.columns]
    parts = first.groupby("signal", sort=False)[["energy_kept_odd", "distortion_odd",
                                                 "even_rms"]].median()
    print(f"\n== {label}: delivered product, the signal itself and what changes for "
          "either polarity (zone medians). odd part (r+ - r-)/2: what the product makes "
          "of the signal; even part (r+ + r-)/2: the day's own field over the interval "
          "left out, which the clean run gave to a drift (even_rms: its RMS over the "
          "signal's)")
    print(kept.join(parts).round(3).to_string())
    print(f"\n== {label}: per zone, energy_kept_odd (distortion_odd, even_rms)")
    for kind, rows in first.groupby("signal", sort=False):
        print(f"  {kind:12s} " + "  ".join(
            f"{r.zone}: {r.energy_kept_odd:.3f} ({r.distortion_odd:.3f}, {r.even_rms:.3f})"
            for r in rows.itertuples()))
    if "distortion_odd_joined" in first.columns:
        print(f"\n== {label}: the odd part once both polarities leave the same rows out "
              "(the union of their left-out rows given): per zone, energy_kept_odd "
              "(distortion_odd) as delivered -> joined; the difference is where the "
              "detector drew the intervals' ends")
        for kind, rows in first.groupby("signal", sort=False):
            print(f"  {kind:12s} " + "  ".join(
                f"{r.zone}: {r.energy_kept_odd:.2f} ({r.distortion_odd:.2f}) -> "
                f"{r.energy_kept_odd_joined:.2f} ({r.distortion_odd_joined:.2f})"
                for r in rows.itertuples()))


def _print_shares(kinds) -> None:
    """Closed-form shares of each signal's energy in polynomials over a 6-min zone."""
    import numpy as np

    from magcal.missions.elfin.injection import polynomial_share, signal_shape

    t = np.arange(0.0, 370.0, 0.1)
    print("\n== share p of each signal's energy in polynomials of degree d over a 370 s "
          "zone, signal centred: what a per-zone drift of that degree takes when nothing "
          "else competes; energy_kept is then (1 - p)^2 (in brackets)")
    for kind in kinds:
        s = signal_shape(kind, t, t0=t[-1] / 2)[:, None]
        shares = [polynomial_share(s, t, d) for d in range(6)]
        print(f"  {kind:12s} " + "  ".join(f"d={d}: {p:.3f} ({(1 - p) ** 2:.3f})"
                                           for d, p in enumerate(shares)))


def main(argv=None) -> int:
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import SIGNALS, run_injections
    from magcal.missions.elfin.linear import CREDIT
    from magcal.missions.elfin.pipeline import ElfinSettings

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--zones", default=",".join(map(str, ZONES)),
                    help="zone numbers (0-based), comma-separated, or 'all'")
    ap.add_argument("--signals", default=",".join(SIGNALS))
    ap.add_argument("--no-held", action="store_true", help="skip the held-phase run")
    ap.add_argument("--settings", nargs="*", default=None, metavar="KEY=VALUE",
                    help="also a run with these ElfinSettings")
    ap.add_argument("--mask-signal", type=float, default=0.0, metavar="FRACTION",
                    help="also a run with the samples where the signal exceeds this "
                         "fraction of its peak left out of every fit (what a fit on "
                         "intervals known to be quiet would keep), e.g. 0.05")
    ap.add_argument("--mask-injected-only", type=float, default=0.0, metavar="FRACTION",
                    help="also a run with those samples left out of the injected run's "
                         "fits only (a detector that flags exactly the signal)")
    ap.add_argument("--centres", default="0.5",
                    help="comma-separated places of the signals in each zone (fractions "
                         "of its span), one run per place, tables joined (default 0.5), "
                         "e.g. --zones all --signals sheet_ew --centres 0.35,0.5,0.65")
    ap.add_argument("--sign", type=float, default=1.0, choices=(1.0, -1.0),
                    help="polarity of every signal (-1: the opposite field; what is kept "
                         "is not odd in the signal)")
    ap.add_argument("--scale", type=float, default=1.0,
                    help="amplitude of every signal in units of its defined one (e.g. 2.5: "
                         "500 nT pulses across B); the polarity is --sign")
    ap.add_argument("--both-signs", action="store_true",
                    help="also inject every signal with the opposite polarity and print "
                         "the part of what came back that follows the signal (odd) and "
                         "the part that does not (even)")
    ap.add_argument("--joined", action="store_true",
                    help="with --both-signs: also both polarities with the union of their "
                         "left-out rows left out (two more calibrations per signal and "
                         "place): the odd part's distortion without the detector's "
                         "polarity-dependent interval ends")
    ap.add_argument("--leave-out", type=float, nargs="?", const=0.05, default=0.0,
                    metavar="FRACTION",
                    help="also, with no signal injected, the clean day calibrated with "
                         "each pulse's rows above this fraction of its peak left out "
                         "(default 0.05): the product's change read against the pulse, "
                         "what a detector that flagged exactly the signal adds to it "
                         "(pulses across B)")
    ap.add_argument("--plot", type=Path, default=None, metavar="DIR",
                    help="write recovered_<signal>.png of the delivered run to DIR (of the "
                         "--settings run to DIR/settings): the injected signal and "
                         "what came back, zone by zone; with --both-signs also "
                         "parts_<signal>.png, the signal's own part and the other")
    args = ap.parse_args(argv)
    if not (args.data / FGS_FILE).is_file():
        print(f"real data not found: {args.data / FGS_FILE}", file=sys.stderr)
        return 2
    fgs, state = read_elfin_fgs(args.data / FGS_FILE), read_elfin_state(args.data / STATE_FILE)
    zones = None if args.zones == "all" else [int(z) for z in args.zones.split(",")]
    import pandas as pd

    kinds = args.signals.split(",")
    centres = [float(c) for c in args.centres.split(",")]
    runs = [] if args.no_held else [("held phase (machinery check)", None, True, 0.0, True)]
    runs.append(("delivered", None, False, 0.0, True))
    if args.settings:
        runs.append((f"settings {' '.join(args.settings)}", _settings(args.settings), False,
                     0.0, True))
    given = ElfinSettings(detect_disturbed=False)      # the interval is given, not found
    if args.mask_signal > 0:
        label = (f"delivered without detection, fitted without the samples above "
                 f"{args.mask_signal:g} of the signal's peak")
        runs.append((label, given, False, args.mask_signal, True))
    if args.mask_injected_only > 0:
        label = (f"delivered without detection, the injected run fitted without the "
                 f"samples above {args.mask_injected_only:g} of the signal's peak (the "
                 "clean run with them)")
        runs.append((label, given, False, args.mask_injected_only, False))
    print(f"ELFIN-A 2022-01-12, zones {args.zones}, signals {', '.join(kinds)}"
          f"{' (opposite polarity)' if args.sign < 0 else ''}, at "
          f"{', '.join(map(str, centres))} of each zone"
          f"{f', amplitudes x {args.scale:g}' if args.scale != 1 else ''}\n{CREDIT}")
    _print_shares(kinds)
    delivered = delivered_clean = None
    for label, settings, hold, mask, mask_clean in runs:
        t0 = time.perf_counter()
        tabs = []
        for centre in centres:
            tab, clean = run_injections(fgs, state, settings, kinds=kinds, zones=zones,
                                        hold=hold, mask_signal=mask, mask_clean=mask_clean,
                                        progress=lambda line: print("  " + line),
                                        plot_dir=_plot_dir(args.plot, label)
                                        if centre == centres[0] else None, centre=centre,
                                        sign=args.sign, scale=args.scale,
                                        both_signs=args.both_signs,
                                        joined=args.joined and args.both_signs and not hold)
            tabs.append(tab.assign(zone=[f"{z}@{centre:g}" for z in tab["zone"]])
                        if len(centres) > 1 else tab)
        tab = pd.concat(tabs, ignore_index=True)
        _print(f"{label} ({time.perf_counter() - t0:.0f} s)", tab, clean)
        if label == "delivered":
            delivered = tab[(tab["product"] == tab["product"].iloc[-1])
                            & (tab["sign"] == args.sign)]
            delivered_clean = clean
    if args.leave_out > 0:
        _print_leave_out(fgs, state, kinds, centres, zones, args.leave_out, delivered,
                         delivered_clean, args.scale)
    return 0


def _print_leave_out(fgs, state, kinds, centres, zones, fraction, delivered, clean,
                     scale) -> None:
    """The leave-out effect per pulse and case, next to the delivered distortion (the
    delivered run's clean day reused)."""
    import numpy as np

    from magcal.missions.elfin.injection import TARGET_DISTORTION
    from magcal.missions.elfin.leave_out import KEPT_BY_LEAVING_OUT, leave_out_effect

    pulses = [k for k in kinds if k in KEPT_BY_LEAVING_OUT]
    others = [k for k in kinds if k not in KEPT_BY_LEAVING_OUT]
    if others:
        print(f"\nleave-out effect: not for {', '.join(others)} (kept by a level step, a "
              "fitted pulse shape or by not being flagged, not by leaving their rows out)")
    if not pulses:
        return
    t0 = time.perf_counter()
    eff = leave_out_effect(fgs, state, kinds=pulses, centres=centres, zones=zones,
                           fraction=fraction, scale=scale, clean=clean,
                           progress=lambda line: print("  " + line))
    case = [f"{z}@{c:g}" if len(centres) > 1 else z for z, c in zip(eff["zone"], eff["centre"])]
    eff = eff.assign(case=case).merge(
        delivered[["signal", "zone", "distortion"]].rename(
            columns={"zone": "case", "distortion": "delivered"}), on=["signal", "case"])
    print(f"\n== leave-out effect ({time.perf_counter() - t0:.0f} s): no signal injected, "
          f"the clean day calibrated with each pulse's rows above {fraction:g} of its peak "
          "left out; the product's change read against the pulse is the distortion a "
          "detector that flagged exactly the pulse adds in the whole-signal reading "
          "(medians; amplitude_for_10%: where that change would be 10 % of the pulse)")
    for kind, g in eff.groupby("signal", sort=False):
        ok, dok = g["distortion"] <= TARGET_DISTORTION, g["delivered"] <= TARGET_DISTORTION
        corr = np.corrcoef(g["distortion"], g["delivered"])[0, 1] if len(g) > 2 else np.nan
        print(f"  {kind:12s} {len(g)} cases, left out {g['left_out_s'].median():.0f} s: "
              f"change {g['distortion'].median():.3f} of the pulse (within 10 % in "
              f"{int(ok.sum())}), delivered {g['delivered'].median():.3f} ({int(dok.sum())}); "
              f"RMS {g['inside_rms_nT'].median():.1f} nT inside, "
              f"{g['outside_rms_nT'].median():.1f} outside, zone shift "
              f"{g['zone_shift_nT'].median():.1f}; amplitude_for_10% "
              f"{g['amplitude_for_target_nT'].median():.0f} nT (90 % of the cases: "
              f"{g['amplitude_for_target_nT'].quantile(0.9):.0f}); per-case correlation "
              f"with the delivered distortion {corr:.2f}")
        print("    per case, change (delivered): " + "  ".join(
            f"{r.case}: {r.distortion:.2f} ({r.delivered:.2f})" for r in g.itertuples()))


def _plot_dir(plot, label):
    """Where a run's pictures go: the delivered run's in ``plot``, the ``--settings``
    run's in ``plot/settings``, none for the other runs."""
    if plot is None:
        return None
    if label == "delivered":
        return plot
    return plot / "settings" if label.startswith("settings ") else None


if __name__ == "__main__":
    raise SystemExit(main())
