"""Least-squares speed on the ELFIN calibration's designs: :func:`magcal.lstsq.lstsq`
(scaled normal equations, one refinement step) against :func:`numpy.linalg.lstsq`
(SVD, the baseline, timed in the same run, the two alternating), with the answers'
largest relative difference.

Designs as the calibration fits them, 3700 samples (a 6-min science zone at 10 Hz):
the linear fit's spin-plane rows (6 columns, two right-hand sides), the robust
baseline of the detection (7 columns), the drifting spin-harmonic correction
(spline drift times harmonics, 66 columns) and the vector step (complex, 45 columns);
and a zone's 120 spin windows of the timing check (86 x 19, three right-hand sides),
solved together (:func:`magcal.lstsq.lstsq_stack`) against one
numpy call per window.

Target: every case at least 1.3x faster than the baseline (the small designs gain
least: the refinement step and the condition estimate cost about what the SVD of six
columns does), the answers within 1e-10 (relative to the largest coefficient).

Run: ``python benchmarks/bench_lstsq.py``
"""

from __future__ import annotations

import numpy as np

from magcal.lstsq import lstsq, lstsq_stack
from magcal.missions.elfin.timing import _design
from timing import best


def _per_window(a, b):
    return np.stack([np.linalg.lstsq(a[j], b[j], rcond=None)[0] for j in range(a.shape[0])])


def _spline_like(t, n_knots):
    """Cubic B-spline-like bumps over ``t`` (columns that overlap their neighbours)."""
    centres = np.linspace(t[0], t[-1], n_knots)
    width = 1.5 * (centres[1] - centres[0])
    return np.clip(1.0 - np.abs(t[:, None] - centres) / width, 0.0, None) ** 3


def main() -> None:
    rng = np.random.default_rng(2022)
    t = np.arange(3700) * 0.1
    x = 2.0 * t / t[-1] - 1.0
    psi = 2.0 * np.pi * t / 2.85                   # ELFIN's spin
    counts = rng.normal(size=(t.size, 3))
    basis = _spline_like(t, 15)
    harm = np.column_stack([f(k * psi)[:, None] * basis for k in (1, 2) for f in (np.cos, np.sin)])
    cases = [
        ("linear fit, spin plane (3700 x 6, 2 rhs)",
         np.column_stack([counts, np.ones_like(x), x, x ** 2]), rng.normal(size=(t.size, 2))),
        ("robust baseline (3700 x 7)",
         np.column_stack([x ** d for d in range(7)]), rng.normal(size=t.size)),
        ("drifting harmonics (3700 x 66)",
         np.column_stack([np.vander(x, 6), harm]), rng.normal(size=t.size)),
        ("vector step, complex (3700 x 45)",
         np.column_stack([np.exp(1j * k * psi)[:, None] * basis for k in (2, 3, 1)]),
         rng.normal(size=t.size) + 1j * rng.normal(size=t.size)),
    ]
    tau = np.linspace(-4.3, 4.3, 86)[None, :] + rng.normal(0, 0.01, (120, 86))
    windows = _design(tau, 2.0 * np.pi / 2.85, 4)[0]         # the timing check's own
    cases.append(("a zone's spin windows (120 x 86 x 19, 3 rhs)", windows,
                  rng.normal(size=(120, 86, 3))))
    for name, a, b in cases:
        calls = 5 if a.ndim == 3 else 50
        numpy_way, magcal_way = ((_per_window, lstsq_stack) if a.ndim == 3 else
                                 (lambda a_, b_: np.linalg.lstsq(a_, b_, rcond=None)[0], lstsq))

        def loop(func):
            def run():
                for _ in range(calls):
                    out = func(a, b)
                return out
            return run

        base_s = fast_s = np.inf
        for _ in range(5):
            seconds, want = best(loop(numpy_way), repeat=1)
            base_s = min(base_s, seconds)
            seconds, got = best(loop(magcal_way), repeat=1)
            fast_s = min(fast_s, seconds)
        diff = float(np.max(np.abs(got - want)) / np.max(np.abs(want)))
        print(f"{name}: numpy {1e3 * base_s / calls:.3f} ms, magcal {1e3 * fast_s / calls:.3f} "
              f"ms = {base_s / fast_s:.1f}x (target >= 1.3x); answers differ by {diff:.1e} "
              "(target <= 1e-10)")


if __name__ == "__main__":
    main()
