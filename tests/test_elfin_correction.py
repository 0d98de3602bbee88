"""Spin-harmonic vector correction (magcal.missions.elfin.harmonic): injected truth."""

from __future__ import annotations

import numpy as np

from magcal.missions.elfin.harmonic import harmonic_vector_correction
from magcal.missions.elfin.scalar import rms
from magcal.spin.despin import spin


def test_injected_cubic_and_drifting_offsets_are_removed_from_the_vectors():
    rng = np.random.default_rng(11)
    t = np.arange(0.0, 360.0, 0.1)
    T = 2 * t / t[-1] - 1
    ang = np.radians(-30 - 40 * (T + 1) / 2)
    perp = 42000 + 3000 * T ** 2
    b_in = np.column_stack([perp * np.cos(ang), perp * np.sin(ang), 2000 - 700 * T])
    truth = spin(b_in, 2 * np.pi * t / 2.85)
    beta = truth[:, 0] + 1j * truth[:, 1]
    eps, b0 = 8e-4, 45000.0                               # the size found on ELFIN-A
    bad = beta + eps * np.conj(beta) ** 3 / b0 ** 2       # cubic spin-plane non-linearity
    bad = bad + (30 * T - 1j * 25 * T ** 2)               # drifting spin-plane offsets
    bad = bad.real * (1 + 5e-4 * T) + 1j * bad.imag       # drifting gain ratio
    measured = np.column_stack([bad.real, bad.imag, truth[:, 2]])
    measured += rng.normal(scale=0.2, size=measured.shape)
    mag = np.linalg.norm(truth, axis=1)
    before = rms(np.linalg.norm(measured - truth, axis=1))
    corrected, info = harmonic_vector_correction(t, measured, mag)
    after = rms(np.linalg.norm(corrected - truth, axis=1))
    assert before > 30.0
    # the drifting gain ratio's isotropic half (a slow |B| change) is not a spin harmonic
    # and stays: 5e-4/2 of |B| at the ends, about 6 nT RMS over the pass
    isotropic = rms(0.5 * 5e-4 * T * np.abs(beta))
    assert after < isotropic + 1.0
    assert info["scalar_fast_after_nT"] < 0.5
    # 4x amplitude at the median |beta|: eps |beta|^4 / (b0^2 |B|)
    med = np.median(np.abs(beta))
    np.testing.assert_allclose(info["fixed_amplitudes_nT"][4],
                               eps * med ** 4 / b0 ** 2 / np.sqrt(med ** 2 + 2000 ** 2), rtol=0.03)
