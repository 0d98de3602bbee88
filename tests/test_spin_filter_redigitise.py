"""On-board recursive filter (Eqs. 1-3) and redigitisation by frequency folding (App. 1)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from magcal.errors import InputError
from magcal.spin.onboard_filter import (corner_frequency, filter_constant,
                                        inverse_recursive_filter, recursive_filter,
                                        transfer_function)
from magcal.spin.redigitise import galileo_times, redigitise


def test_filter_corner_matches_paper():
    # A = 1/4 at 30 samples/s: "fc ~ 1.6 Hz"
    assert_allclose(corner_frequency(0.25, 30.0), 15.0 / (3 * np.pi), rtol=1e-12)
    assert 1.55 < corner_frequency(0.25, 30.0) < 1.65
    assert_allclose(filter_constant(corner_frequency(0.25, 30.0), 30.0), 0.25, rtol=1e-12)


def test_filter_response_matches_transfer_function(rng):
    fs, a = 30.0, 0.25
    t = np.arange(30000) / fs
    for f in (0.05, 0.5, 1.6, 5.0):
        y = recursive_filter(np.sin(2 * np.pi * f * t), a)[3000:]
        tt = t[3000:]
        design = np.column_stack([np.sin(2 * np.pi * f * tt), np.cos(2 * np.pi * f * tt)])
        s, c = np.linalg.lstsq(design, y, rcond=None)[0]
        h = transfer_function(f, a, fs)
        assert_allclose(np.hypot(s, c), abs(h), rtol=1e-6)
        assert_allclose(np.arctan2(c, s), np.angle(h), atol=1e-6)
    # near-unit gain at spin frequencies (0.05 Hz): "T is close to unit amplitude"
    assert abs(abs(transfer_function(0.1, a, fs)) - 1) < 0.005


def test_inverse_filter_recovers_input(rng):
    x = rng.standard_normal((500, 3))
    for a in (0.25, 512 / 32768):
        assert_allclose(inverse_recursive_filter(recursive_filter(x, a), a), x, atol=1e-8)
        y0 = recursive_filter(x, a, initial=np.zeros(3))
        assert_allclose(inverse_recursive_filter(y0, a, initial=np.zeros(3)), x, atol=1e-8)


def _amplitude_spectrum(v, dt):
    w = np.hanning(v.size)
    return np.fft.rfftfreq(v.size, dt), np.abs(np.fft.rfft(v * w)) / (w.sum() / 2)


def _peak(f, spec, at):
    i = int(np.argmin(np.abs(f - at)))
    return spec[i - 3:i + 4].max()


def test_fig_a1_1_ghosts_vanish():
    """A 1 Hz sine at the Galileo spacing, treated as equispaced, has ghosts at 0.5 and
    2 Hz (Fig. A1-1 top); linear interpolation only diminishes them (middle); after
    redigitisation they are gone (bottom)."""
    t = galileo_times(900)
    x = np.sin(2 * np.pi * 1.0 * t)
    dt = 2.0 / 9.0
    grid = np.arange(t.size) * dt
    f, raw = _amplitude_spectrum(x, dt)
    _, lin = _amplitude_spectrum(np.interp(grid, t, x), dt)
    _, fixed = _amplitude_spectrum(redigitise(x), dt)
    _, ref = _amplitude_spectrum(np.sin(2 * np.pi * grid), dt)
    for ghost in (0.5, 2.0):
        assert _peak(f, raw, ghost) > 0.03                     # ~4 % ghosts before
        assert 1e-4 < _peak(f, lin, ghost) < _peak(f, raw, ghost)
        assert _peak(f, fixed, ghost) < 1e-6                   # none after
        assert _peak(f, fixed, ghost) < 10 * _peak(f, ref, ghost) + 1e-9
    assert_allclose(_peak(f, fixed, 1.0), 1.0, atol=1e-3)
    # and in the time domain: the equispaced series itself
    assert_allclose(redigitise(x)[20:-20], np.sin(2 * np.pi * grid)[20:-20], atol=1e-3)


def test_redigitise_vectors_and_bad_input():
    t = galileo_times(300)
    x = np.column_stack([np.sin(2 * np.pi * 0.2 * t), np.cos(2 * np.pi * 1.7 * t)])
    y = redigitise(x)
    grid = np.arange(t.size) * 2 / 9
    assert y.shape == x.shape
    assert_allclose(y[30:-30, 0], np.sin(2 * np.pi * 0.2 * grid[30:-30]), atol=0.02)
    with pytest.raises(InputError, match="multiple of 3"):
        redigitise(x[:-1])
    bad = x.copy()
    bad[4, 0] = np.nan
    with pytest.raises(InputError, match="gap-free"):
        redigitise(bad)
