"""High-pass filtering before the PiCoG variance analysis.

A correction ``A`` acts on the data linearly and sample by sample, so it can be fitted on
any linearly filtered copy of the sensors and applied to the raw data: if
``b_i = B + p_i s(t)`` then ``F b_i = F B + p_i F s(t)`` for any linear time-invariant
filter ``F``. Removing running means over ``highpass_s`` seconds takes out the slow
ambient variation (daily variation, substorm growth and recovery) that otherwise
dominates long windows (the paper's 16000 s third order, §4.2 and §5), while the ramps,
spikes and oscillations of the disturbers pass.
"""

from __future__ import annotations

import numpy as np

from magcal.errors import InputError


def running_mean(x: np.ndarray, n: int) -> np.ndarray:
    """Centred running mean over ``n`` samples, ignoring NaN; NaN where ``x`` is NaN.

    Windows are shortened at the ends. Rows with any NaN are left out of the means.

    Parameters
    ----------
    x : ndarray, shape (m,) or (m, k)
    n : int
        Window length in samples (>= 1).

    Returns
    -------
    ndarray, same shape as ``x``

    Examples
    --------
    >>> running_mean(np.array([0.0, 3.0, 6.0, np.nan, 12.0]), 3).tolist()
    [1.5, 3.0, 4.5, nan, 12.0]
    """
    x = np.asarray(x, dtype=float)
    one_d = x.ndim == 1
    x2 = x[:, None] if one_d else x
    n = int(n)
    if n < 1:
        raise InputError(f"running-mean length must be at least 1 sample, got {n}")
    ok = np.all(np.isfinite(x2), axis=1)
    m = x2.shape[0]
    z = np.where(ok[:, None], x2, 0.0)
    cs = np.concatenate([np.zeros((1, x2.shape[1])), np.cumsum(z, axis=0)])
    cnt = np.concatenate([[0], np.cumsum(ok, dtype=np.int64)])
    half = n // 2
    lo = np.clip(np.arange(m) - half, 0, m)
    hi = np.clip(np.arange(m) - half + n, 0, m)
    k = (cnt[hi] - cnt[lo]).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (cs[hi] - cs[lo]) / k[:, None]
    out[~ok] = np.nan
    return out[:, 0] if one_d else out


def highpass(x: np.ndarray, n: int | None) -> np.ndarray:
    """``x`` minus its centred running mean over ``n`` samples (``None``: unchanged).

    Examples
    --------
    >>> t = np.arange(2000.0)
    >>> slow = 50 * np.sin(2 * np.pi * t / 86400)          # a daily variation
    >>> fast = np.sign(np.sin(2 * np.pi * t / 200))        # a 200 s square wave
    >>> y = highpass(slow + fast, 400)
    >>> bool(np.max(np.abs(y[400:-400] - fast[400:-400])) < 0.02)
    True
    """
    if n is None:
        return np.asarray(x, dtype=float)
    return np.asarray(x, dtype=float) - running_mean(x, n)


def highpass_samples(highpass_s: float | None, dt_s: float) -> int | None:
    """Running-mean length in samples for ``highpass_s`` seconds (None or 0: off).

    Examples
    --------
    >>> highpass_samples(1800.0, 0.5), highpass_samples(None, 1.0)
    (3600, None)
    """
    if highpass_s is None or highpass_s == 0:
        return None
    if not highpass_s > 0:
        raise InputError(f"highpass_s must be positive, got {highpass_s}")
    return max(3, int(round(float(highpass_s) / float(dt_s))))


def bandpass(x: np.ndarray, band_hz, dt_s: float) -> np.ndarray:
    """Ideal (FFT) band-pass of ``x`` keeping frequencies in ``band_hz = (lo, hi)``.

    NaN rows are set to zero for the transform and are NaN again in the output. A
    spectral line (the 6 s tone of GK-2A) is a pure sinusoid, so the band can be as
    narrow as a few frequency bins of the whole record; inside it the line dominates
    broadband disturbers that are much larger overall. Linear, so a correction fitted
    on band-passed data applies to the raw data (see the module docstring).

    Examples
    --------
    >>> t = np.arange(6000.0)
    >>> x = np.sin(2 * np.pi * t / 6) + np.sin(2 * np.pi * t / 100)
    >>> y = bandpass(x, (0.16, 0.17), 1.0)
    >>> bool(np.max(np.abs(y - np.sin(2 * np.pi * t / 6))) < 1e-9)
    True
    """
    lo, hi = (float(v) for v in band_hz)
    if not 0 <= lo < hi:
        raise InputError(f"band_hz must be [low, high] with 0 <= low < high, got {band_hz}")
    x = np.asarray(x, dtype=float)
    one_d = x.ndim == 1
    x2 = x[:, None] if one_d else x
    ok = np.all(np.isfinite(x2), axis=1)
    z = np.where(ok[:, None], x2, 0.0)
    spec = np.fft.rfft(z, axis=0)
    f = np.fft.rfftfreq(z.shape[0], float(dt_s))
    keep = (f >= lo) & (f <= hi)
    if not keep.any():
        raise InputError(f"band {lo:g}-{hi:g} Hz holds no frequency of a {z.shape[0]}-sample "
                         f"record at {dt_s:g} s")
    spec[~keep] = 0.0
    out = np.fft.irfft(spec, z.shape[0], axis=0)
    out[~ok] = np.nan
    return out[:, 0] if one_d else out
