"""The offsets split at level changes (``OffsetEstimator(split_at_level_changes=True)``)
against the default product, on simulated records with a known offset.

Records as in ``bench_levels_power.py`` (90-182 days at 5-min cadence, an offset plus
a 3 nT OU model miss of the given correlation time and 0.5 nT white noise, quiet data
in whole 3-hour Kp blocks), here with the true offset of every sample kept. The
windows' ``min_used`` is 144 samples (12 h of 5-min data, as 720 is of 1-min data).

* ``steps``: a step of 3 or 5 nT (Hp, -0.6x in He, 0.4x in Hn) at a random day in the
  middle 60 % of the record, under a 1-hour or a 6-hour miss: RMS error of the applied
  offset against the true one, per component, over the 14 days either side of the step
  and over the whole record (every sample, quiet or not), default and split.
* ``drifting``: the same records with a drift of 0.04 nT/day as well (the demo's), where
  holding a segment's end value out to the change costs the drift over the distance.
* ``nostep``: no step (plain misses of 1 h to 5 days; a drift of 0.05 nT/day; a
  120-day wander of 3 or 5 nT): the same RMS errors, and how many records had a change
  named (the only ones whose split product differs).
* Coverage (both runs): the share of valid windows whose 95 % interval (``t(0.975,
  dof) se``) holds the true offset at the window's centre, per component, for the
  split pieces by length and for unsplit windows not straddling a true step.

Each record is fitted once by default and once split with ``min_piece_days=0``; the
split product for a minimum piece length ``L`` is that table with the pieces shorter
than ``L`` set to NaN (what the estimator does with ``min_piece_days=L``).

Run: ``python benchmarks/bench_offsets_segments.py steps|drifting|nostep [-n 30]
[--workers 1]``.
Seeds 0.. (steps) and 500.. (nostep); ``--held`` adds 1000.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections import defaultdict
from multiprocessing import Pool

import numpy as np

from magcal.alignment.noise import simulate_ou
from magcal.offsets import OffsetEstimator

DAY_S = 86400.0
DAY_NS = 86_400 * 10**9
DIRECTION = np.array([1.0, -0.6, 0.4])
BASE = np.array([4.0, -2.0, 1.0])
#: Minimum piece lengths (days) compared.
MIN_PIECES = (0.0, 3.0, 5.0, 7.0, 10.0, 14.0, 21.0)
#: Piece-length bins (days) of the coverage table.
LENGTH_BINS = (0.0, 3.0, 5.0, 7.0, 10.0, 14.0, 21.0, 28.1)


def record(seed, tau_h, step=0.0, drift=0.0, wander=0.0):
    """Times (ns), data minus model, Kp (0 quiet, 3 not), the true offset of every
    sample, and the true step day (None without one)."""
    rng = np.random.default_rng(seed)
    days = int(rng.integers(90, 183))
    cad = 300.0
    t_s = np.arange(int(days * DAY_S / cad)) * cad
    miss = np.stack([simulate_ou(rng, t_s, 3.0, tau_h * 3600.0) for _ in range(3)], 1)
    truth = np.tile(BASE, (t_s.size, 1))
    truth += drift * (t_s / DAY_S)[:, None] * np.array([1.0, 0.5, -0.7])
    truth += wander * np.sin(2 * np.pi * t_s[:, None] / (120 * DAY_S)
                             + rng.uniform(0, 6.3, 3))
    d1 = None
    if step:
        d1 = rng.uniform(0.2, 0.8) * days
        truth += step * DIRECTION * (t_s >= d1 * DAY_S)[:, None]
    x = truth + miss + 0.5 * rng.standard_normal(miss.shape)
    p_quiet = rng.uniform(0.5, 0.7)
    blocks = rng.random(int(np.ceil(t_s.size * cad / 10800)) + 1) < p_quiet
    kp = np.where(blocks[(t_s // 10800).astype(int)], 0.0, 3.0)
    return (t_s * 1e9).astype(np.int64), x, kp, truth, d1


def _rms(err, mask):
    return np.sqrt(np.mean(err[mask] ** 2, axis=0)) if mask.any() else np.full(3, np.nan)


def _coverage_rows(tab, t, truth, step_ns, piece):
    """(length days, is piece, straddles a true step, covered (3,), |error| (3,)) per
    valid window with a standard error."""
    half = tab.interval95()
    c = tab.center.astype(np.int64)
    idx = np.clip(np.searchsorted(t, c), 0, t.size - 1)
    s, e = tab.start.astype(np.int64), tab.end.astype(np.int64)
    rows = []
    for k in np.flatnonzero(tab.valid & np.all(np.isfinite(half), axis=1)):
        straddle = step_ns is not None and s[k] < step_ns < e[k]
        err = tab.offset_nT[k] - truth[idx[k]]
        rows.append(((e[k] - s[k]) / DAY_NS, bool(piece[k]), straddle,
                     np.abs(err) <= half[k], np.abs(err)))
    return rows


def run(job):
    seed, tau_h, kw = job
    t, x, kp, truth, d1 = record(seed, tau_h, **kw)
    zeros = np.zeros_like(x)
    e0 = OffsetEstimator(min_used=144).fit(t.astype("datetime64[ns]"), x, zeros, kp)
    e1 = OffsetEstimator(min_used=144, split_at_level_changes=True,
                         min_piece_days=0.0).fit(t.astype("datetime64[ns]"), x, zeros, kp)
    step_ns = None if d1 is None else int(d1 * DAY_NS)
    near = (np.zeros(t.size, dtype=bool) if d1 is None
            else np.abs(t - step_ns) <= 14 * DAY_NS)
    every = np.ones(t.size, dtype=bool)
    tt = t.astype("datetime64[ns]")
    from magcal.offsets.apply import apply_offsets

    out = {"found": len(e1.level_changes_), "rms": {}}
    err0 = e0.apply(tt, x)[1] - truth
    out["rms"]["default"] = (_rms(err0, near), _rms(err0, every))
    tab = e1.table_
    length = (tab.end - tab.start) / np.timedelta64(1, "D")
    whole = e0.table_
    piece = ~np.isin(tab.start.astype(np.int64), whole.start.astype(np.int64)) | \
        ~np.isin(tab.end.astype(np.int64), whole.end.astype(np.int64))
    for lmin in MIN_PIECES:
        short = piece & (length < lmin)
        t_l = dataclasses.replace(tab, offset_nT=np.where(short[:, None], np.nan,
                                                          tab.offset_nT))
        err1 = apply_offsets(tt, x, t_l)[1] - truth
        out["rms"][f"split{lmin:g}"] = (_rms(err1, near), _rms(err1, every))
    out["cover_default"] = _coverage_rows(whole, t, truth, step_ns,
                                          np.zeros(len(whole), dtype=bool))
    out["cover_split"] = _coverage_rows(tab, t, truth, step_ns, piece)
    out["change_days"] = [float(np.datetime64(c.time, "ns").astype(np.int64)) / DAY_NS
                          for c in e1.level_changes_]
    out["step_day"] = d1
    return tau_h, tuple(sorted(kw.items())), out


def jobs(which, n, base):
    out = []
    if which in ("steps", "drifting"):
        drift = {"drift": 0.04} if which == "drifting" else {}
        for tau in (1, 6):
            for s in (3.0, 5.0):
                out += [(base + i, tau, {"step": s, **drift}) for i in range(n)]
    else:
        for tau in (1, 6, 24, 120):
            out += [(base + 500 + i, tau, {}) for i in range(n)]
        for kw in ({"drift": 0.05}, {"wander": 3.0}, {"wander": 5.0}):
            for j, tau in enumerate((1, 6, 24)):
                out += [(base + 600 + 40 * j + i, tau, dict(kw)) for i in range(n // 2)]
    return out


def _summarise(results, which):
    cells = defaultdict(list)
    for tau, kw, out in results:
        cells[(tau, kw)].append(out)
    keys = ["default"] + [f"split{m:g}" for m in MIN_PIECES]
    print("RMS error of the applied offset (nT, Hp/He/Hn), mean over records of the "
          "per-record RMS")
    for (tau, kw), outs in sorted(cells.items()):
        found = sum(o["found"] > 0 for o in outs)
        print(f"\n{tau:4d} h {dict(kw)}  records {len(outs)}, with a change named {found}")
        for part, label in ((0, "+-14 d"), (1, "record")):
            if which == "nostep" and part == 0:
                continue
            for k in keys:
                v = np.array([o["rms"][k][part] for o in outs])
                line = f"  {label:7s} {k:9s} " + " ".join(f"{m:.3f}" for m in v.mean(0))
                if which != "nostep":
                    f = np.array([o["found"] > 0 for o in outs])
                    if f.any():
                        line += "   found only: " + " ".join(f"{m:.3f}" for m in
                                                             v[f].mean(0))
                else:
                    diff = np.array([np.abs(o["rms"][k][1] - o["rms"]["default"][1]).max()
                                     for o in outs])
                    line += f"   records differing {int(np.sum(diff > 1e-12))}"
                    if np.any(diff > 1e-12):
                        worse = max(o["rms"][k][1].max() - o["rms"]["default"][1].max()
                                    for o in outs)
                        line += f" worst rms increase {worse:+.3f}"
                print(line)
    print("\nCoverage of the 95 % intervals (valid windows with an error; share holding the "
          "truth at the centre, Hp/He/Hn; median |error| Hp)")
    split = [r for _, _, o in results for r in o["cover_split"]]
    default = [r for _, _, o in results for r in o["cover_default"]]

    def show(label, rows):
        if not rows:
            print(f"  {label:32s} none")
            return
        cov = np.array([r[3] for r in rows]).mean(0)
        err = np.median([r[4][0] for r in rows])
        print(f"  {label:32s} n={len(rows):5d} " + " ".join(f"{c:.3f}" for c in cov)
              + f"  med|err| {err:.3f}")

    show("default, not straddling", [r for r in default if not r[2]])
    show("default, straddling a step", [r for r in default if r[2]])
    show("split, whole windows, no step in", [r for r in split if not r[1] and not r[2]])
    show("split, whole windows, step in", [r for r in split if not r[1] and r[2]])
    for lo, hi in zip(LENGTH_BINS[:-1], LENGTH_BINS[1:]):
        show(f"split pieces {lo:g}-{hi:g} d, no step in",
             [r for r in split if r[1] and lo <= r[0] < hi and not r[2]])
        show(f"split pieces {lo:g}-{hi:g} d, step in",
             [r for r in split if r[1] and lo <= r[0] < hi and r[2]])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("which", choices=("steps", "drifting", "nostep"))
    ap.add_argument("-n", type=int, default=30)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--held", action="store_true")
    a = ap.parse_args()
    todo = jobs(a.which, a.n, 1000 if a.held else 0)
    if a.workers > 1:
        with Pool(a.workers) as pool:
            results = pool.map(run, todo, chunksize=2)
    else:
        results = [run(j) for j in todo]
    _summarise(results, a.which)


if __name__ == "__main__":
    main()
