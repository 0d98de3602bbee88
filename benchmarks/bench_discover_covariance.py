"""Speed of the discovery loop's standard errors: :func:`magcal.discover.selection.
model_covariance` on the calls of one discovery run, against the same formula written
the plain way (the baseline, timed in the same run), with the answers' largest relative
difference.

The run: a simulated month at 60 s (43,200 x 3 samples, red model error, benign
substorms and ULF waves) with a hidden drift, as the suite's discovery cases. The loop
asks for about 130 covariances, most of one coefficient.

Fast path: the lags the Bartlett sums need by transforms of ``n + lags`` points (the
autocorrelation time's window first within 2048 lags), the fitted regressors of every
coefficient by one matrix product, and the block-weighted cross sums by one weighted
Gram matrix. Baseline: transforms of ``2n`` points at every lag, one accumulation per
coefficient and column, and one ``bincount`` per coefficient pair and component.

Target: at least 1.3x faster than the baseline, the answers within 1e-10 (relative to
the largest element of each matrix).

Run: ``python benchmarks/bench_discover_covariance.py``
"""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path

import numpy as np

from magcal.discover import selection

TARGET_RATIO = 1.3


@contextlib.contextmanager
def _full_transforms():
    """The library's autocorrelations with the transforms they had: ``2n`` points, and
    the autocorrelation time's window sought at every lag at once."""
    from scipy.fft import irfft, next_fast_len, rfft

    def full(v, lags):
        nfft = next_fast_len(2 * max(v.shape[0], 1), real=True)
        f = rfft(v, nfft, axis=0)
        return irfft((f * np.conj(f)).real, nfft, axis=0)[:lags]

    saved = selection._lag_sums, selection._FIRST_LAGS
    selection._lag_sums, selection._FIRST_LAGS = full, 1 << 62
    try:
        yield
    finally:
        selection._lag_sums, selection._FIRST_LAGS = saved


def covariance_baseline(gram, score, params, blocks, max_lag=1440):
    """:func:`~magcal.discover.selection.model_covariance` written the plain way."""
    cols = list(score.columns)
    blocks = np.asarray(blocks)
    B = gram.n_blocks
    Minv, resid, s2 = selection._covariance_inputs(gram, score, blocks)
    a = [gram.fitted(cols, Minv[:, j]) for j in params]
    p = len(params)
    cov = np.zeros((p, p))
    for c in range(gram.m):
        active = [i for i in range(p) if a[i][:, c].any()]
        if not active:
            continue
        with _full_transforms():
            tau_e = selection.integrated_autocorr_time(resid[:, c])
            rho_e = selection.autocorrelation(resid[:, c], int(min(max(5 * tau_e, 10), max_lag)))
            k = rho_e.size
            rho_a = selection.autocorrelation(np.column_stack([a[i][:, c] for i in active]),
                                              k - 1, centre=False)
        tau = {i: max(selection.TAU_FLOOR, 1.0 + 2.0 * float(rho_e[1:k] @ rho_a[1:k, q]))
               for q, i in enumerate(active)}
        for ii, i in enumerate(active):
            for j in active[ii:]:
                e = np.bincount(blocks, weights=a[i][:, c] * a[j][:, c], minlength=B)
                v = np.sqrt(tau[i] * tau[j]) * float(e @ s2[:, c])
                cov[i, j] += v
                if j != i:
                    cov[j, i] += v
    return cov


def _calls():
    """The covariance calls of one discovery run on the suite's drift case."""
    import magcal.discover.loop as loop

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from test_discover_cases import _axes, _run, make_case

    calls = []
    library = loop.model_covariance

    def record(gram, score, params, blocks, *args, **kwargs):
        calls.append((gram, score, list(params), blocks))
        return library(gram, score, params, blocks, *args, **kwargs)

    _, _, day, _ = _axes()
    loop.model_covariance = record
    try:
        _run(make_case({"drift": np.outer(day - 15, [0.25, -0.15, 0.0])}))
    finally:
        loop.model_covariance = library
    return calls


def main() -> int:
    calls = _calls()
    print(f"{len(calls)} covariance calls of one discovery run "
          f"({calls[0][0].n} x {calls[0][0].m} samples)")
    times = {"library": [], "baseline": []}
    for _ in range(3):  # alternating, best of three
        for name, func in (("library", selection.model_covariance),
                           ("baseline", covariance_baseline)):
            t0 = time.perf_counter()
            out = [func(*call) for call in calls]
            times[name].append(time.perf_counter() - t0)
            if name == "library":
                fast = out
            else:
                slow = out
    worst = max(float(np.max(np.abs(f - s)) / max(np.max(np.abs(s)), 1e-300))
                for f, s in zip(fast, slow))
    lib, base = min(times["library"]), min(times["baseline"])
    ratio = base / lib
    print(f"model_covariance: library {lib:.3f} s, baseline {base:.3f} s -> {ratio:.2f}x "
          f"(target >= {TARGET_RATIO}x); largest relative difference {worst:.1e} "
          "(target <= 1e-10)")
    return 0 if ratio >= TARGET_RATIO and worst <= 1e-10 else 1


if __name__ == "__main__":
    raise SystemExit(main())
