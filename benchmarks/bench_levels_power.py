"""Power and false changes of :func:`magcal.offsets.levels.detect_level_changes` on
simulated records.

Records of 90-182 days at 5-min cadence: an offset plus a 3 nT OU model miss
(:func:`magcal.alignment.noise.simulate_ou`) of the given correlation time, 0.5 nT white
noise, quiet data in whole 3-hour Kp blocks (each quiet with a probability drawn from
0.5-0.7 per record) or, with ``--iid``, 70 % of samples quiet at random. Steps are ``s``
nT in Hp, ``-0.6 s`` in He and ``0.4 s`` in Hn. A step counts as found when a change is
named within 2 days of it or with it inside its 95 % interval; any other change named is
a false one. Seeds 0-29 (dev) or 1000-1029 (``--held``).

Run: ``python benchmarks/bench_levels_power.py power|false|two [--iid] [--held] [-n 30]
[--tau 24 120] [--plain]`` (``--tau``: only those correlation times; ``--plain``: of
``false``, only the records without drift, wander, gap or spikes).
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from multiprocessing import Pool

import numpy as np

from magcal.alignment.noise import simulate_ou
from magcal.offsets.levels import detect_level_changes

DAY_S = 86400.0
DIRECTION = np.array([1.0, -0.6, 0.4])


def record(seed, tau_h, step=0.0, kpblocks=True, drift=0.0, wander=0.0, gap=0,
           spikes=False, two=False):
    """Times (ns) and residuals of the quiet samples, and the true change days."""
    rng = np.random.default_rng(seed)
    days = int(rng.integers(90, 183))
    cad = 300.0
    t_s = np.arange(int(days * DAY_S / cad)) * cad
    miss = np.stack([simulate_ou(rng, t_s, 3.0, tau_h * 3600.0) for _ in range(3)], 1)
    x = np.array([4.0, -2.0, 1.0]) + miss + 0.5 * rng.standard_normal(miss.shape)
    x += drift * (t_s / DAY_S)[:, None] * np.array([1.0, 0.5, -0.7])
    x += wander * np.sin(2 * np.pi * t_s[:, None] / (120 * DAY_S) + rng.uniform(0, 6.3, 3))
    truth = []
    if two:  # 4 nT, then -3 nT 40 or more days later
        d1 = rng.uniform(0.25, 0.4) * days
        d2 = min(d1 + rng.uniform(40, 0.55 * days), days - 15)
        x += 4.0 * DIRECTION * (t_s >= d1 * DAY_S)[:, None]
        x += -3.0 * DIRECTION * (t_s >= d2 * DAY_S)[:, None]
        truth = [d1, d2]
    elif step:
        d1 = rng.uniform(0.2, 0.8) * days
        x += step * DIRECTION * (t_s >= d1 * DAY_S)[:, None]
        truth = [d1]
    if kpblocks:
        p_quiet = rng.uniform(0.5, 0.7)
        blocks = rng.random(int(np.ceil(t_s.size * cad / 10800)) + 1) < p_quiet
        quiet = blocks[(t_s // 10800).astype(int)]
    else:
        quiet = rng.random(t_s.size) < 0.7
    if gap:
        g0 = rng.uniform(0.2, 0.7) * days
        quiet &= ~((t_s >= g0 * DAY_S) & (t_s < (g0 + gap) * DAY_S))
    if spikes:
        k = rng.random(t_s.size) < 0.005
        x[k] += rng.uniform(30, 300, (k.sum(), 1)) * rng.choice([-1, 1], (k.sum(), 3))
    return (t_s[quiet] * 1e9).astype(np.int64), x[quiet], truth


def run(job):
    seed, tau_h, kw = job
    t, x, truth = record(seed, tau_h, **kw)
    changes, _ = detect_level_changes(t, x)
    day = [float(np.datetime64(c.time, "ns").astype(np.int64)) / (DAY_S * 1e9)
           for c in changes]
    ci = [tuple(float(np.datetime64(v, "ns").astype(np.int64)) / (DAY_S * 1e9)
                for v in (c.time_lo, c.time_hi)) for c in changes]

    def near(f, c, tr):
        return abs(f - tr) <= 2.0 or c[0] <= tr <= c[1]

    hits = [any(near(f, c, tr) for f, c in zip(day, ci)) for tr in truth]
    false = sum(all(not near(f, c, tr) for tr in truth) for f, c in zip(day, ci))
    return tau_h, str(kw), hits, false


def jobs(which, base, n, iid, taus=(1, 6, 24, 120), plain=False):
    q = {"kpblocks": False} if iid else {}
    out = []
    if which == "power":
        for tau in taus:
            for s in (1, 2, 3, 5):
                out += [(base + i, tau, dict(q, step=s)) for i in range(n)]
    elif which == "false":
        for tau in taus:
            out += [(base + 100 + i, tau, dict(q)) for i in range(n)]
        for kw in () if plain else ({"drift": 0.05}, {"wander": 3.0}, {"wander": 5.0},
                                    {"gap": 7}, {"gap": 10}, {"spikes": True}):
            for j, tau in enumerate((1, 6, 24, 120)):
                if tau in taus:
                    out += [(base + 200 + 40 * j + i, tau, dict(q, **kw))
                            for i in range(n // 2)]
    elif which == "two":
        for tau in (1, 6):
            if tau in taus:
                out += [(base + 300 + i, tau, dict(q, two=True)) for i in range(n)]
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("which", choices=("power", "false", "two"))
    ap.add_argument("--iid", action="store_true")
    ap.add_argument("--held", action="store_true")
    ap.add_argument("-n", type=int, default=30)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--tau", type=int, nargs="+", default=[1, 6, 24, 120])
    ap.add_argument("--plain", action="store_true")
    a = ap.parse_args()
    with Pool(a.workers) as pool:
        todo = jobs(a.which, 1000 if a.held else 0, a.n, a.iid, a.tau, a.plain)
        results = pool.map(run, todo, chunksize=4)
    cells = defaultdict(list)
    for tau, kw, hits, false in results:
        cells[(tau, kw)].append((hits, false))
    for (tau, kw), rs in sorted(cells.items()):
        found = sum(sum(h) for h, _ in rs)
        both = sum(all(h) for h, _ in rs if len(h) > 1)
        print(f"{tau:4d} h {kw:40s} found {found}/{sum(len(h) for h, _ in rs)}"
              f"{f' both {both}' if a.which == 'two' else ''}"
              f"  records naming a false change {sum(f > 0 for _, f in rs)}/{len(rs)}")


if __name__ == "__main__":
    main()
