"""Kalman whitening speed: the sqrt(n)-block stepping of varying gains against stepping
one sample at a time (the baseline, the same recursion in a plain loop, timed in the
same run), on the records where the gains keep changing: a quarter of 1-min data with
a quiet-time selection's gaps (two-scale model) and two weeks of nearly white 1-min
data (OU + white with a long correlation time).

Target: at least 5x faster than the baseline on both, innovations equal to 1e-12.

The gains of OU + white noise on a month of 1-min data with 5 % of the samples missing
at random (runs of about 20 equal spacings, where the gains never settle): the
block-stepped Riccati variances against the one-sample recursion in a plain loop.
Target: at least 1.5x, gains equal to 1e-12.

Run: ``python benchmarks/bench_whitening.py``
"""

from __future__ import annotations

import numpy as np

from magcal.alignment.ouwhite import kalman_gains, whiten
from magcal.alignment.twoscale import state_gains, whiten_state
from timing import best


def one_at_a_time(y, phi, k, f):
    """Baseline: the innovations of ``s_i = diag(phi_i) s_(i-1) + k_i e_i``, sample by sample."""
    y = np.asarray(y, dtype=float)
    phi, k = phi.reshape(len(y), -1), k.reshape(len(y), -1)
    state = np.zeros((phi.shape[1], y.shape[1]))
    e = np.empty_like(y)
    for i in range(len(y)):
        pred = phi[i][:, None] * state
        e[i] = y[i] - pred.sum(axis=0)
        state = pred + k[i][:, None] * e[i]
    return e / np.sqrt(f)[:, None]


def gains_one_at_a_time(phi, s2, w2):
    """Baseline: the Kalman gain and innovation variance of OU + white noise, sample by
    sample (``p`` the filtered variance, from zero)."""
    k, f, p = np.empty(phi.size), np.empty(phi.size), 0.0
    for i, ph in enumerate(phi.tolist()):
        m = ph * ph * p + s2 * (1.0 - ph * ph)
        f[i] = m + w2
        k[i] = m / f[i]
        p = (1.0 - k[i]) * m
    return k, f


def main() -> None:
    rng = np.random.default_rng(2019)
    t = np.arange(91 * 1440) * 60.0
    quiet = np.repeat(rng.random(91 * 8 + 1) > 0.35, 180)[:t.size]  # 3 h Kp blocks
    cases = []
    tq = t[quiet]
    g2 = state_gains(tq, (600.0, 86400.0), np.array([0.2, 0.75, 0.05]))
    cases.append(("quarter, quiet selection, two-scale", tq, g2,
                  lambda y: whiten_state(y, g2)))
    tw = t[:14 * 1440]
    g1 = kalman_gains(tw, 1e7, 0.999)
    cases.append(("two weeks, nearly white OU + white", tw, g1, lambda y: whiten(y, g1)))
    for name, times, gains, fast in cases:
        y = rng.normal(size=(times.size, 8))
        base_s, ref = best(lambda: one_at_a_time(y, gains.phi, gains.k, gains.f), repeat=1)
        fast_s, out = best(lambda: fast(y))
        diff = float(np.max(np.abs(out - ref)))
        print(f"{name} ({times.size} samples x 8 columns): one at a time {base_s * 1e3:.0f} ms, "
              f"magcal {fast_s * 1e3:.1f} ms = {base_s / fast_s:.1f}x (target >= 5x); "
              f"max difference {diff:.1e} (target <= 1e-12)")
    ts = t[:30 * 1440][rng.random(30 * 1440) >= 0.05]
    fast_s, g = best(lambda: kalman_gains(ts, 3600.0, 0.3))
    base_s, (k, f) = best(lambda: gains_one_at_a_time(g.phi, 0.7, 0.3), repeat=1)
    diff = max(float(np.max(np.abs(g.k / k - 1))), float(np.max(np.abs(g.f / f - 1))))
    print(f"gains, a month with 5 % scattered gaps ({ts.size} samples): one at a time "
          f"{base_s * 1e3:.0f} ms, magcal {fast_s * 1e3:.1f} ms = {base_s / fast_s:.1f}x "
          f"(target >= 1.5x); max relative difference {diff:.1e} (target <= 1e-12)")


if __name__ == "__main__":
    main()
