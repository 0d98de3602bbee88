"""Spin-ripple stated errors against the truth on records with random phases.

For each case, seeded records from :func:`simulate_spinning` with ``random_phases=True``
(the waves', slow field's and spin phases drawn per record) are fitted with the fixed
parameters' priors from the truth, as the tests do. Printed per determinable parameter:
coverage of the 95 % interval (|z| <= 1.96, z = error / stated std), RMS of z, spread
(standard deviation) and mean of z, and the RMS error against the truth of the
bias-corrected fit over that of the plain least-squares fit (``correct_bias=False``).

Run: ``python benchmarks/bench_ripple_phases.py [first_seed [n_records]]``
(default seeds 5000-5199).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from magcal.simulate.spinning import SpinningConfig, simulate_spinning
from magcal.spin.ripple import DETERMINABLE, PARAM_NAMES, fit_spin_ripple

CASES = {
    "galileo 5 h": SpinningConfig.galileo_like(random_phases=True),
    "galileo 5 h, 1 nT red, 0.05 nT noise": SpinningConfig.galileo_like(
        random_phases=True, turbulence_rms_nT=1.0, noise_nT=0.05),
    "galileo 1 h": SpinningConfig.galileo_like(duration_s=3600.0, random_phases=True),
    "elfin-like pass": SpinningConfig.elfin_like(random_phases=True),
    "elfin-like pass, white noise": SpinningConfig.elfin_like(random_phases=True,
                                                               turbulence_rms_nT=0.0),
}


def errors(config, seeds):
    """Errors of the corrected fit, its stated std, errors of the plain fit and of the fit
    with the leakage left in (records x 8)."""
    err, std, plain, left = [], [], [], []
    for seed in seeds:
        res = simulate_spinning(config, rng=np.random.default_rng(seed))
        tr, d = res.truth, res.data
        c0 = np.eye(3)
        c0[0] = tr.coupling[0]
        c0[2, 2] = tr.coupling[2, 2]
        o0 = np.array([0.0, 0.0, tr.offsets_nT[2]])
        args = (tr.t_s, d[["b1", "b2", "b3"]].to_numpy(), d["phase"].to_numpy())
        full = np.concatenate([tr.coupling.ravel(), tr.offsets_nT])
        truth = np.array([full[PARAM_NAMES.index(n)] for n in DETERMINABLE])
        cal = fit_spin_ripple(*args, coupling0=c0, offsets0=o0)
        raw = fit_spin_ripple(*args, coupling0=c0, offsets0=o0, correct_bias=False)
        leaky = fit_spin_ripple(*args, coupling0=c0, offsets0=o0, correct_leakage=False)
        err.append([cal.parameter(n) for n in DETERMINABLE] - truth)
        plain.append([raw.parameter(n) for n in DETERMINABLE] - truth)
        left.append([leaky.parameter(n) for n in DETERMINABLE] - truth)
        std.append([cal.std[n] for n in DETERMINABLE])
    return np.array(err), np.array(std), np.array(plain), np.array(left)


def table(err, std, plain, left) -> str:
    z = err / std
    rows = [f"{'':8s}" + "".join(f"{n:>8s}" for n in DETERMINABLE)]
    for label, values in (
            ("cover %", 100 * np.mean(np.abs(z) <= 1.96, axis=0)),
            ("rms z", np.sqrt(np.mean(z ** 2, axis=0))),
            ("std z", z.std(axis=0)),
            ("mean z", z.mean(axis=0)),
            ("rms/raw", np.sqrt(np.mean(err ** 2, axis=0) / np.mean(plain ** 2, axis=0))),
            ("rms/left", np.sqrt(np.mean(err ** 2, axis=0) / np.mean(left ** 2, axis=0)))):
        rows.append(f"{label:8s}" + "".join(f"{v:8.3f}" for v in values))
    rows.append(f"all: coverage {100 * np.mean(np.abs(z) <= 1.96):.1f} %")
    return "\n".join(rows)


def main() -> None:
    first = int(sys.argv[1]) if len(sys.argv) > 1 else 5000
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 200
    seeds = range(first, first + n)
    for name, config in CASES.items():
        start = time.perf_counter()
        out = errors(config, seeds)
        print(f"== {name}: seeds {first}-{first + n - 1} "
              f"({time.perf_counter() - start:.0f} s)")
        print(table(*out))


if __name__ == "__main__":
    main()
