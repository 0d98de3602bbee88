"""Alignment angles by time window (e.g. monthly), to show drift and its spread."""

from __future__ import annotations

import dataclasses

import numpy as np

from magcal.alignment.gls import fit_alignment
from magcal.alignment.noise import COMPONENTS
from magcal.errors import InputError
from magcal.io.jsonio import product_dict


@dataclasses.dataclass(frozen=True)
class WindowAngles:
    """Angles fitted separately in consecutive time windows.

    Attributes
    ----------
    start, end : ndarray of datetime64[ns], shape (k,)
    angles_deg, std_deg : ndarray, shape (k, 3)
    n_used : ndarray of int, shape (k,)
    mean_deg, mean_std_deg : ndarray, shape (3,)
        Inverse-variance weighted mean over windows and its standard deviation.
    spread_deg : ndarray, shape (3,)
        Standard deviation of the window angles about their mean (the paper's "std").
    chi2_per_dof : ndarray, shape (3,)
        Scatter of the windows about the mean in units of their own errors: about 1
        when the angle is constant, larger when it drifts or varies.
    drift_deg_per_day, drift_std_deg_per_day : ndarray, shape (3,)
        Weighted linear trend of the window angles.
    """

    start: np.ndarray
    end: np.ndarray
    angles_deg: np.ndarray
    std_deg: np.ndarray
    n_used: np.ndarray
    mean_deg: np.ndarray
    mean_std_deg: np.ndarray
    spread_deg: np.ndarray
    chi2_per_dof: np.ndarray
    drift_deg_per_day: np.ndarray
    drift_std_deg_per_day: np.ndarray

    @property
    def center(self) -> np.ndarray:
        """Window centres (datetime64[ns])."""
        return self.start + (self.end - self.start) // 2

    def to_json(self) -> dict:
        """JSON-ready product dictionary."""
        def comp(v):
            return {c: float(x) for c, x in zip(COMPONENTS, v)}

        return product_dict({
            "windows": [
                {"start": str(s), "end": str(e), "n_used": int(n),
                 "angles_deg": comp(a), "std_deg": comp(sd)}
                for s, e, n, a, sd in zip(self.start, self.end, self.n_used,
                                          self.angles_deg, self.std_deg)],
            "mean_deg": comp(self.mean_deg), "mean_std_deg": comp(self.mean_std_deg),
            "spread_deg": comp(self.spread_deg), "chi2_per_dof": comp(self.chi2_per_dof),
            "drift_deg_per_day": comp(self.drift_deg_per_day),
            "drift_std_deg_per_day": comp(self.drift_std_deg_per_day),
        })


def angles_by_window(times, data, ref, window_s: float, step_s: float | None = None,
                     min_samples: int = 100, **fit_kwargs) -> WindowAngles:
    """Fit the alignment in consecutive (or sliding) windows.

    Parameters
    ----------
    times : array_like of datetime64, shape (n,)
    data, ref : array_like, shape (n, 3)
    window_s : float
        Window length in seconds (30 days = 2,592,000).
    step_s : float, optional
        Step between window starts (default: ``window_s``, non-overlapping).
    min_samples : int
        Windows with fewer finite samples are skipped.
    **fit_kwargs
        Passed to :func:`magcal.alignment.gls.fit_alignment`.

    Returns
    -------
    WindowAngles

    Examples
    --------
    >>> from magcal.alignment.synthetic import synthetic_pair
    >>> case = synthetic_pair(np.random.default_rng(0), n=2016, cadence_s=300.0,
    ...                       noise_tau_s=(1800.0,) * 3)
    >>> win = angles_by_window(case.times, case.data, case.ref, window_s=2 * 86400.0)
    >>> win.angles_deg.shape
    (4, 3)
    """
    t = np.asarray(times).astype("datetime64[ns]")
    if not np.issubdtype(t.dtype, np.datetime64):
        raise InputError("angles_by_window needs datetime64 times")
    d = np.asarray(data, dtype=float)
    r = np.asarray(ref, dtype=float)
    lon = fit_kwargs.pop("lon_deg", None)
    per_sample_lon = lon is not None and np.ndim(lon) > 0
    win = np.timedelta64(int(window_s * 1e9), "ns")
    step = win if step_s is None else np.timedelta64(int(step_s * 1e9), "ns")
    starts, ends, angles, stds, ns = [], [], [], [], []
    s = t[0]
    while s <= t[-1]:
        e = s + win
        sel = (t >= s) & (t < e)
        finite = sel & np.isfinite(d).all(axis=1) & np.isfinite(r).all(axis=1)
        if finite.sum() >= min_samples:
            res = fit_alignment(t[sel], d[sel], r[sel],
                                lon_deg=np.asarray(lon)[sel] if per_sample_lon else lon,
                                **fit_kwargs)
            starts.append(s)
            ends.append(e)
            angles.append(res.angles_deg)
            stds.append(res.std_deg)
            ns.append(res.n_used)
        s = s + step
    if len(angles) < 1:
        raise InputError(f"no window of {window_s:g} s holds {min_samples} finite samples")
    a, sd = np.array(angles), np.array(stds)
    wts = 1.0 / sd ** 2
    mean = np.sum(wts * a, axis=0) / np.sum(wts, axis=0)
    mean_std = 1.0 / np.sqrt(np.sum(wts, axis=0))
    k = a.shape[0]
    spread = a.std(axis=0, ddof=1) if k > 1 else np.full(3, np.nan)
    chi2 = (np.sum(wts * (a - mean) ** 2, axis=0) / (k - 1)) if k > 1 else np.full(3, np.nan)
    starts_arr = np.array(starts, dtype="datetime64[ns]")
    ends_arr = np.array(ends, dtype="datetime64[ns]")
    centre_days = ((starts_arr - starts_arr[0]) + (ends_arr - starts_arr) / 2).astype(
        "int64") / 86400e9
    drift = np.full(3, np.nan)
    drift_std = np.full(3, np.nan)
    if k > 2:
        for c in range(3):
            x = np.stack([np.ones(k), centre_days], axis=1)
            cov = np.linalg.inv(x.T @ (wts[:, c:c + 1] * x))
            beta = cov @ x.T @ (wts[:, c] * a[:, c])
            drift[c], drift_std[c] = beta[1], np.sqrt(cov[1, 1])
    return WindowAngles(start=starts_arr, end=ends_arr, angles_deg=a, std_deg=sd,
                        n_used=np.array(ns), mean_deg=mean, mean_std_deg=mean_std,
                        spread_deg=spread, chi2_per_dof=chi2, drift_deg_per_day=drift,
                        drift_std_deg_per_day=drift_std)
