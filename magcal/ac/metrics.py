"""Quality metrics of AC cleaning (Constantinescu et al. 2020, §4.2 Table 1, §5).

- PSD of raw and cleaned data (Welch, 512 s segments) and the mean reduction factor over
  period bands (2 s - 1 min, 1 min - 6 h);
- remnants per disturbance class: ramp size from medians over 90 s before and after,
  spike height against the median over 20 s intervals 5 s before and after the peak,
  peak-to-peak of high-frequency noise against a quiet etalon;
- stability of repeated fits: std of directions (deg) and alpha, and Bmaxdev, the
  largest change of the corrected field for parameter changes of one std;
- the error model of Eq. 38 for sensor placement.

All functions take arrays with explicit sampling (``dt_s``) or sample indices.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from magcal.errors import InputError

#: The paper's two period bands (s): 2 s - 1 min and 1 min - 6 h.
PAPER_BANDS_S = ((2.0, 60.0), (60.0, 6 * 3600.0))


def fill_nan(x: np.ndarray) -> np.ndarray:
    """Linear interpolation over NaN gaps per column, as an (n, k) copy.

    Spectra and median filters need finite input; ends are held at the nearest value.

    Examples
    --------
    >>> fill_nan(np.array([1.0, np.nan, 3.0, np.nan])).ravel().tolist()
    [1.0, 2.0, 3.0, 3.0]
    """
    x = np.array(x, dtype=float, copy=True)
    if x.ndim == 1:
        x = x[:, None]
    idx = np.arange(x.shape[0])
    for k in range(x.shape[1]):
        ok = np.isfinite(x[:, k])
        if not ok.any():
            raise InputError("a component has no valid sample")
        if not ok.all():
            x[~ok, k] = np.interp(idx[~ok], idx[ok], x[ok, k])
    return x


def psd(b: np.ndarray, dt_s: float, segment_s: float | None = 512.0):
    """Total power spectral density (sum over components), Welch.

    Parameters
    ----------
    b : ndarray (n, 3) or (n,)
    dt_s : float
        Sample spacing (s).
    segment_s : float or None
        Welch segment length (the paper: 512 s); None: one segment, no windowing
        (the paper's low-frequency PSD).

    Returns
    -------
    f_hz, p : ndarray
        Frequencies and total PSD (nT^2/Hz).

    Examples
    --------
    >>> t = np.arange(4096.0)
    >>> f, p = psd(np.sin(2 * np.pi * t / 16), 1.0)
    >>> float(f[np.argmax(p)])
    0.0625
    """
    x = fill_nan(b)
    fs = 1.0 / dt_s
    if segment_s is None:
        f, p = signal.periodogram(x, fs=fs, window="boxcar", detrend="constant", axis=0)
    else:
        nper = min(int(round(segment_s / dt_s)), x.shape[0])
        f, p = signal.welch(x, fs=fs, nperseg=nper, detrend="constant", axis=0)
    return f, p.sum(axis=1)


def band_reduction(b_raw, b_clean, dt_s, bands_s=PAPER_BANDS_S, segment_s=512.0,
                   low_segment_s=None, split_s=60.0) -> list[dict]:
    """Mean PSD ratio raw/cleaned over period bands (the paper's 7.8 and 3.9).

    Bands with periods below ``split_s`` use Welch with ``segment_s``; longer periods
    use ``low_segment_s`` (None: the whole series, as the paper did for 1 min - 6 h).

    Returns
    -------
    list of dict ``{"band_s": [lo, hi], "mean_ratio": r, "n_freq": k}``

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> x = rng.normal(size=(20000, 3))
    >>> out = band_reduction(x, x / 2, 1.0, bands_s=[(2.0, 60.0)])
    >>> round(out[0]["mean_ratio"], 6)
    4.0
    """
    out = []
    for lo, hi in bands_s:
        seg = segment_s if hi <= split_s else low_segment_s
        f, p_raw = psd(b_raw, dt_s, seg)
        _, p_cln = psd(b_clean, dt_s, seg)
        with np.errstate(divide="ignore"):
            period = np.where(f > 0, 1.0 / f, np.inf)
        sel = (period >= lo) & (period <= hi) & (p_cln > 0)
        ratio = float(np.mean(p_raw[sel] / p_cln[sel])) if sel.any() else float("nan")
        out.append({"band_s": [lo, hi], "mean_ratio": ratio, "n_freq": int(sel.sum())})
    return out


def disturbance_power_ratio(before: np.ndarray, after: np.ndarray) -> float:
    """Power (mean-removed, summed over components) before / after.

    Examples
    --------
    >>> round(disturbance_power_ratio(np.array([[1.0], [-1.0]]), np.array([[0.1], [-0.1]])), 9)
    100.0
    """
    def power(x):
        x = np.asarray(x, dtype=float)
        ok = np.all(np.isfinite(x), axis=1) if x.ndim == 2 else np.isfinite(x)
        x = x[ok] - x[ok].mean(axis=0)
        return float(np.sum(x ** 2) / max(len(x), 1))
    return power(before) / power(after)


def ramp_size(b: np.ndarray, index: int, dt_s: float, span_s: float = 90.0,
              gap_s: float = 0.0) -> np.ndarray:
    """Ramp (step) size at sample ``index``: median over ``span_s`` after minus before.

    Examples
    --------
    >>> x = np.r_[np.zeros(200), np.ones(200) * 3.0]
    >>> float(ramp_size(x, 200, 1.0))
    3.0
    """
    b = np.asarray(b, dtype=float)
    n = int(round(span_s / dt_s))
    g = int(round(gap_s / dt_s))
    lo, hi = max(0, index - g - n), min(b.shape[0], index + g + n)
    before = np.nanmedian(b[lo:max(lo + 1, index - g)], axis=0)
    after = np.nanmedian(b[min(index + g, hi - 1):hi], axis=0)
    return after - before


def spike_height(b: np.ndarray, index: int, dt_s: float, span_s: float = 20.0,
                 gap_s: float = 5.0) -> np.ndarray:
    """Spike height: value at the peak minus the median over ``span_s`` intervals
    ``gap_s`` before and after the peak (the paper: 20 s, 5 s).

    Examples
    --------
    >>> x = np.zeros(100); x[50] = 4.0
    >>> float(spike_height(x, 50, 1.0))
    4.0
    """
    b = np.asarray(b, dtype=float)
    n = int(round(span_s / dt_s))
    g = int(round(gap_s / dt_s))
    pre = b[max(0, index - g - n):max(0, index - g)]
    post = b[index + g + 1:index + g + 1 + n]
    base = np.nanmedian(np.concatenate([pre, post]), axis=0)
    return b[index] - base


def peak_to_peak(b: np.ndarray, block_n: int) -> np.ndarray:
    """Mean peak-to-peak amplitude over consecutive blocks of ``block_n`` samples.

    Examples
    --------
    >>> float(peak_to_peak(np.tile([0.0, 2.0], 50), 10))
    2.0
    """
    b = np.asarray(b, dtype=float)
    m = (b.shape[0] // block_n) * block_n
    blocks = b[:m].reshape((m // block_n, block_n) + b.shape[1:])
    return np.nanmean(np.nanmax(blocks, axis=1) - np.nanmin(blocks, axis=1), axis=0)


def hf_remnant(b: np.ndarray, quiet: slice, disturbed: slice, block_n: int) -> np.ndarray:
    """High-frequency disturbance: mean peak-to-peak in ``disturbed`` minus in the quiet
    etalon interval ``quiet`` (the paper's Table 2 definition)."""
    b = np.asarray(b, dtype=float)
    return peak_to_peak(b[disturbed], block_n) - peak_to_peak(b[quiet], block_n)


def angle_deg(u, v) -> np.ndarray:
    """Axial angle between unit vectors (deg, in [0, 90])."""
    c = np.abs(np.sum(np.asarray(u) * np.asarray(v), axis=-1))
    return np.degrees(np.arccos(np.clip(c, 0.0, 1.0)))


def parameter_stability(steps_list: list[list[dict]]) -> list[dict]:
    """Std of directions and alpha per step over repeated fits (Table 1 rows).

    Parameters
    ----------
    steps_list : list of PARAMS-style step lists (same plan, one per fit).

    Returns
    -------
    list of dict per step: ``stage, order, i, j, std_direction_i_deg,
    std_direction_ij_deg, std_alpha, mean_alpha, n_fits``. Direction std is the RMS
    angle to the axial mean direction.
    """
    out = []
    for k, first in enumerate(steps_list[0]):
        rows = [s[k] for s in steps_list]
        rec = {key: first[key] for key in ("stage", "order", "i", "j")}
        for which in ("direction_i", "direction_ij"):
            v = np.array([r[which] for r in rows], dtype=float)
            mean = np.linalg.eigh(v.T @ v)[1][:, 2]
            rec[f"std_{which}_deg"] = float(np.sqrt(np.mean(angle_deg(v, mean) ** 2)))
        a = np.array([r["alpha"] * np.sign(np.dot(r["direction_i"], first["direction_i"]))
                      * np.sign(np.dot(r["direction_ij"], first["direction_ij"])) for r in rows])
        rec.update(std_alpha=float(a.std(ddof=1)) if len(a) > 1 else 0.0,
                   mean_alpha=float(a.mean()), n_fits=len(rows))
        out.append(rec)
    return out


def rotate_toward(v: np.ndarray, angle_deg_: float, seed_axis=None) -> np.ndarray:
    """Unit vector at ``angle_deg_`` from ``v`` (in the plane with ``seed_axis``)."""
    v = np.asarray(v, dtype=float)
    a = np.array([1.0, 0.0, 0.0]) if seed_axis is None else np.asarray(seed_axis, float)
    w = a - (a @ v) * v
    if np.linalg.norm(w) < 1e-9:
        w = np.cross(v, [0.0, 1.0, 0.0])
    w /= np.linalg.norm(w)
    t = np.radians(angle_deg_)
    return np.cos(t) * v + np.sin(t) * w


def bmaxdev(data: dict, steps: list[dict], stability: list[dict], rebuild) -> dict:
    """Maximum change of the corrected field for parameter deviations of one std.

    Parameters
    ----------
    data : dict sensor -> (n, 3)
    steps : fitted steps (PARAMS style), the nominal parameters
    stability : output of :func:`parameter_stability` for the same steps
    rebuild : callable(steps) -> M dict
        Rebuilds the upload matrices from (possibly perturbed) steps.

    Returns
    -------
    dict with ``per_parameter`` (max |dB| for each single direction / alpha change, nT)
    and ``all`` (all deviations at once, signs chosen to add up), Table-1 style.
    """
    from magcal.ac.chain import apply_weights

    nominal = apply_weights(data, rebuild(steps))
    per = []
    combined = [dict(s) for s in steps]
    for k, (s, st) in enumerate(zip(steps, stability)):
        for which, key in (("direction_i", "std_direction_i_deg"),
                           ("direction_ij", "std_direction_ij_deg"), ("alpha", "std_alpha")):
            pert = [dict(x) for x in steps]
            if which == "alpha":
                pert[k]["alpha"] = s["alpha"] + st[key]
                combined[k]["alpha"] = s["alpha"] + st[key]
            else:
                newv = rotate_toward(np.asarray(s[which], float), st[key]).tolist()
                pert[k][which] = newv
                combined[k][which] = newv
            dev = float(np.nanmax(np.abs(apply_weights(data, rebuild(pert)) - nominal)))
            per.append({"stage": s["stage"], "order": s["order"], "i": s["i"],
                        "parameter": which, "max_change_nT": dev})
    dev_all = float(np.nanmax(np.abs(apply_weights(data, rebuild(combined)) - nominal)))
    return {"per_parameter": per, "all": dev_all}


def error_model_eq38(x, z_ratio: float = 1.0, bq_over_zs: float = 0.0) -> np.ndarray:
    """Eq. 38: error of the dipole correction relative to the outboard noise ``Z_s``.

    ``eps / Z_s = (1 + x^3 Z_t/Z_s + (1/x - 1) b_qs/Z_s) / (1 - x^3)`` with
    ``x = r_t / r_s < 1`` the inboard position relative to the outboard one.

    Examples
    --------
    >>> float(error_model_eq38(0.0))     # sensor at the dipole: only outboard noise
    1.0

    Optimum inboard position for b_qs = (0.1, 1, 10) Z_s; the paper (Fig. 8) quotes
    about 0.6 and 0.8 for the last two and "almost mid-distance" for the first:

    >>> x = np.linspace(0.01, 0.99, 981)
    >>> [round(float(x[np.argmin(error_model_eq38(x, 1.0, q))]), 2) for q in (0.1, 1, 10)]
    [0.35, 0.56, 0.78]
    """
    x = np.asarray(x, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        quad = np.where(x > 0, (1.0 / np.where(x > 0, x, 1.0) - 1.0) * bq_over_zs, 0.0)
    return (1.0 + x ** 3 * z_ratio + quad) / (1.0 - x ** 3)


def _event_indices(t_s: np.ndarray, times_s, margin_s: float) -> np.ndarray:
    """Sample indices of event times at least ``margin_s`` away from both ends."""
    t_s = np.asarray(t_s, dtype=float)
    times_s = np.atleast_1d(np.asarray(times_s, dtype=float))
    keep = (times_s >= t_s[0] + margin_s) & (times_s <= t_s[-1] - margin_s)
    return np.searchsorted(t_s, times_s[keep])


def ramp_sizes(b: np.ndarray, t_s: np.ndarray, times_s, *, span_s: float = 90.0,
               gap_s: float = 15.0) -> np.ndarray:
    """Ramp sizes (Table 2: median over ``span_s`` after minus before) at event times.

    ``gap_s`` skips the ramp itself on both sides of the event time (half the ramp
    duration). Events closer than ``span_s + gap_s`` to an end are left out.

    Returns
    -------
    ndarray, shape (n_events, 3)

    Examples
    --------
    >>> t = np.arange(1000.0)
    >>> b = np.c_[np.where(t >= 500, 2.0, 0.0), 0.01 * t, np.zeros(1000)]
    >>> np.round(ramp_sizes(b, t, [500.0]), 6).tolist()   # step 2; trend 0.01 x (90 + 2 x 15)
    [[2.0, 1.2, 0.0]]
    """
    dt = float(np.median(np.diff(np.asarray(t_s, dtype=float))))
    idx = _event_indices(t_s, times_s, span_s + gap_s)
    return np.array([ramp_size(b, int(i), dt, span_s, gap_s) for i in idx]).reshape(-1, 3)


def spike_heights(b: np.ndarray, t_s: np.ndarray, times_s, *, span_s: float = 20.0,
                  gap_s: float = 5.0, search_s: float = 2.0) -> np.ndarray:
    """Spike heights (Table 2) at event times: the sample of largest |deviation| within
    ``search_s`` of each time minus the median over ``span_s`` intervals ``gap_s``
    before and after it.

    Returns
    -------
    ndarray, shape (n_events, 3)

    Examples
    --------
    >>> t = np.arange(200.0)
    >>> b = np.c_[3.0 * np.exp(-0.5 * ((t - 100.4) / 1.5) ** 2), np.zeros(200), 0.5 * np.ones(200)]
    >>> np.round(spike_heights(b, t, [100.4]), 3).tolist()
    [[2.895, 0.0, 0.0]]
    """
    b = np.asarray(b, dtype=float)
    t_s = np.asarray(t_s, dtype=float)
    dt = float(np.median(np.diff(t_s)))
    idx = _event_indices(t_s, times_s, span_s + gap_s + search_s)
    w = int(round(search_s / dt))
    out = []
    for i in idx:
        seg = b[i - w:i + w + 1]
        base = np.nanmedian(b[max(0, i - w - 60):i + w + 60], axis=0)
        peak = i - w + int(np.nanargmax(np.sum((seg - base) ** 2, axis=1)))
        out.append(spike_height(b, peak, dt, span_s, gap_s))
    return np.array(out).reshape(-1, 3)


def hf_peak_to_peak(b: np.ndarray, t_s: np.ndarray, quiet_s, disturbed_s, *,
                    block_s: float = 60.0) -> np.ndarray:
    """High-frequency disturbance magnitude (Table 2): mean peak-to-peak amplitude over
    ``block_s`` blocks in ``disturbed_s = (start, end)`` minus that in the quiet etalon
    ``quiet_s = (start, end)``; per component, with a linear trend removed from each
    block so the slow ambient field does not count.

    Examples
    --------
    A 1 nT two-sample pulse in the middle of every 60 s block after 600 s, on a trend:

    >>> t = np.arange(1200.0)
    >>> pulse = np.tile(np.r_[np.zeros(29), 1.0, 1.0, np.zeros(29)], 20) * (t >= 600)
    >>> b = np.c_[pulse, 0.02 * t, 0 * t]
    >>> np.round(hf_peak_to_peak(b, t, (0, 600), (600, 1200)), 6).tolist()
    [1.0, 0.0, 0.0]
    """
    b = np.asarray(b, dtype=float)
    t_s = np.asarray(t_s, dtype=float)
    dt = float(np.median(np.diff(t_s)))
    block_n = max(3, int(round(block_s / dt)))

    def p2p(lo, hi):
        sel = (t_s >= lo) & (t_s < hi)
        x = b[sel]
        m = (x.shape[0] // block_n) * block_n
        if m == 0:
            raise InputError(f"interval ({lo}, {hi}) is shorter than one {block_s} s block")
        blocks = x[:m].reshape(m // block_n, block_n, 3)
        tt = np.arange(block_n, dtype=float) - (block_n - 1) / 2.0
        slope = np.einsum("k,nkc->nc", tt, blocks) / np.sum(tt ** 2)
        res = blocks - blocks.mean(axis=1, keepdims=True) - slope[:, None, :] * tt[None, :, None]
        return np.nanmean(np.nanmax(res, axis=1) - np.nanmin(res, axis=1), axis=0)

    return p2p(*disturbed_s) - p2p(*quiet_s)
