"""Is the cleaned product better than the raw sensor in every band and component?

An AC cleaning is a linear combination of the sensors, so it can lower the power in the
band of a disturber and raise it elsewhere (the partner sensor's own noise enters with
the correction, a fit on a short record follows the ambient field). A product must not
be worse than the raw target anywhere without saying so: :func:`band_check` compares
the power spectra of the raw target and of the cleaned product per band and component
and lists the bands where the cleaned power is higher.

Bands are scaled to the record: Welch segments of an eighth of the record (at most
``max_segment_s``), half-octave bands from four frequency bins up to the Nyquist
frequency, merged upwards until each band holds ``min_bins`` bins.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from magcal.ac.metrics import fill_nan
from magcal.errors import InputError

COMPONENTS = ("x", "y", "z")
#: a band is worse than raw when the cleaned power exceeds the raw power by this factor
WORSE_FACTOR = 1.1


def record_bands_hz(n: int, dt_s: float, *, min_bins: int = 6, max_segment_s: float = 86400.0,
                    ratio: float = np.sqrt(2.0)) -> tuple[list[tuple[float, float]], int]:
    """Frequency bands (Hz) scaled to a record of ``n`` samples at ``dt_s``.

    Returns
    -------
    bands : list of (low, high)
    nperseg : int
        Welch segment length (samples) the bands were made for.

    Examples
    --------
    A 2-minute record at 128 Hz: bands from 0.27 Hz to the 64 Hz Nyquist frequency.

    >>> bands, nper = record_bands_hz(15153, 1 / 128)
    >>> nper, round(bands[0][0], 2), bands[-1][1]
    (1894, 0.27, 64.0)
    """
    nper = int(min(n // 8, round(max_segment_s / dt_s)))
    if nper < 4 * min_bins:
        raise InputError(f"the record ({n} samples) is too short for a band check")
    df = 1.0 / (nper * dt_s)
    nyq = 0.5 / dt_s
    edges = [4 * df]
    while edges[-1] * ratio < nyq:
        edges.append(edges[-1] * ratio)
    edges.append(nyq)
    bands, lo = [], edges[0]
    for hi in edges[1:]:
        if (hi - lo) / df >= min_bins:
            bands.append((lo, hi))
            lo = hi
    if lo < nyq:
        if bands:
            bands[-1] = (bands[-1][0], nyq)
        else:
            bands.append((lo, nyq))
    return bands, nper


#: A gap longer than this fraction of the samples held splits a record into pieces whose
#: spectra are averaged (:func:`data_pieces`); shorter gaps are interpolated.
LONG_GAP_FRACTION = 0.1


def data_pieces(raw, clean, long_gap_fraction: float = LONG_GAP_FRACTION) -> list[slice]:
    """The pieces of a record between its long gaps, longest first.

    A gap (rows where ``raw`` or ``clean`` misses a component) longer than
    ``long_gap_fraction`` of the rows held splits the record: interpolated, a gap of a
    week between two hours of data is a week-long straight line, whose spectrum, and
    the step between the product's and raw's lines, decided the band check. Shorter
    gaps stay inside a piece (interpolated, as before). A record without a long gap is
    one piece: the whole record.

    Examples
    --------
    >>> x = np.zeros((100, 3)); x[30:80] = np.nan          # a gap as long as the data
    >>> [(s.start, s.stop) for s in data_pieces(x, x)]
    [(0, 30), (80, 100)]
    >>> x = np.zeros((100, 3)); x[30:33] = np.nan
    >>> [(s.start, s.stop) for s in data_pieces(x, x)]
    [(0, 100)]
    """
    raw, clean = np.asarray(raw, dtype=float), np.asarray(clean, dtype=float)
    ok = (np.isfinite(raw).reshape(len(raw), -1).all(axis=1)
          & np.isfinite(clean).reshape(len(clean), -1).all(axis=1))
    n = ok.size
    if ok.all() or not ok.any():
        return [slice(0, n)]
    edges = np.flatnonzero(np.diff(np.r_[0, (~ok).astype(np.int8), 0]))
    long_gaps = [(a, b) for a, b in zip(edges[::2], edges[1::2])
                 if b - a > long_gap_fraction * ok.sum() and 0 < a and b < n]
    if not long_gaps:
        return [slice(0, n)]
    held = np.flatnonzero(ok)
    bounds = [int(held[0])] + [v for a, b in long_gaps for v in (int(a), int(b))] + \
        [int(held[-1]) + 1]
    pieces = [slice(bounds[i], bounds[i + 1]) for i in range(0, len(bounds), 2)]
    return sorted(pieces, key=lambda sl: sl.stop - sl.start, reverse=True)


@dataclass(frozen=True)
class BandCheck:
    """Raw and cleaned power per band and component (see :func:`band_check`)."""

    bands_hz: tuple          #: ((low, high), ...)
    raw_power: np.ndarray    #: (n_bands, 3) mean PSD of the raw target, nT^2/Hz
    clean_power: np.ndarray  #: (n_bands, 3) mean PSD of the cleaned product
    worse_factor: float

    @property
    def reduction(self) -> np.ndarray:
        """Raw over cleaned power, (n_bands, 3) (> 1: the cleaning removed power)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.raw_power / self.clean_power

    @property
    def worse_than_raw(self) -> list[dict]:
        """Bands and components where the cleaned power exceeds the raw by
        ``worse_factor``."""
        red = self.reduction
        out = []
        for b, (lo, hi) in enumerate(self.bands_hz):
            for k, c in enumerate(COMPONENTS):
                if red[b, k] * self.worse_factor < 1.0:
                    out.append({"band_hz": [float(lo), float(hi)], "component": c,
                                "reduction": float(red[b, k])})
        return out

    def lines(self) -> list[str]:
        """One line per band: the reduction of each component."""
        red = self.reduction
        return [f"{lo:9.4g}-{hi:<9.4g} Hz: " + "  ".join(
                    f"{c} {red[b, k]:7.3g}x" for k, c in enumerate(COMPONENTS))
                for b, (lo, hi) in enumerate(self.bands_hz)]

    def to_dict(self) -> dict:
        return {"bands_hz": [[float(lo), float(hi)] for lo, hi in self.bands_hz],
                "raw_psd_nT2_per_Hz": self.raw_power.tolist(),
                "clean_psd_nT2_per_Hz": self.clean_power.tolist(),
                "reduction": self.reduction.tolist(), "worse_factor": self.worse_factor,
                "definition": "mean Welch PSD per band, raw target over cleaned product; "
                              "worse: cleaned power above raw by worse_factor"}


def band_check(raw: np.ndarray, clean: np.ndarray, dt_s: float, *, bands_hz=None,
               worse_factor: float = WORSE_FACTOR) -> BandCheck:
    """Compare the spectra of the raw target and the cleaned product per band.

    Parameters
    ----------
    raw, clean : ndarray (n, 3)
        Raw target and cleaned product on the same uniform grid (NaN gaps are
        interpolated for the spectra).
    dt_s : float
    bands_hz : list of (low, high), optional
        Default: :func:`record_bands_hz`.

    Examples
    --------
    A 35 Hz tone removed, white noise doubled in y:

    >>> rng = np.random.default_rng(0); t = np.arange(16384) / 128
    >>> amb = rng.normal(0, 0.01, (16384, 3))
    >>> tone = np.sin(2 * np.pi * 35 * t)[:, None] * [1.0, 0.0, 0.0]
    >>> chk = band_check(amb + tone, amb * [1.0, 2.0, 1.0], 1 / 128)
    >>> sorted({w["component"] for w in chk.worse_than_raw})
    ['y']
    >>> bool(chk.reduction[[lo <= 35 < hi for lo, hi in chk.bands_hz]][0, 0] > 1e3)
    True
    """
    raw, clean = np.asarray(raw, dtype=float), np.asarray(clean, dtype=float)
    # long gaps: the spectra of the pieces between them (the longest first), not of the
    # lines interpolated across; a record without one is a single piece
    pieces = data_pieces(raw, clean)
    n = pieces[0].stop - pieces[0].start
    if bands_hz is None:
        bands_hz, nper = record_bands_hz(n, dt_s)
    else:
        nper = min(n, max(64, n // 8))

    def psd(x, piece):
        return signal.welch(fill_nan(x[piece]), fs=1.0 / dt_s, nperseg=nper, axis=0)

    f, p_raw = psd(raw, pieces[0])
    _, p_cln = psd(clean, pieces[0])
    if len(pieces) > 1:  # the others that hold a Welch segment, weighted by their count
        weight = n // nper
        p_raw, p_cln = p_raw * weight, p_cln * weight
        for piece in pieces[1:]:
            w = (piece.stop - piece.start) // nper
            if w == 0:
                continue
            p_raw = p_raw + w * psd(raw, piece)[1]
            p_cln = p_cln + w * psd(clean, piece)[1]
            weight += w
        p_raw, p_cln = p_raw / weight, p_cln / weight
    rp, cp = [], []
    for lo, hi in bands_hz:
        sel = (f >= lo) & (f < hi) if hi < f[-1] else (f >= lo) & (f <= hi)
        rp.append(p_raw[sel].mean(axis=0) if sel.any() else np.full(3, np.nan))
        cp.append(p_cln[sel].mean(axis=0) if sel.any() else np.full(3, np.nan))
    return BandCheck(bands_hz=tuple((float(lo), float(hi)) for lo, hi in bands_hz),
                     raw_power=np.array(rp), clean_power=np.array(cp),
                     worse_factor=float(worse_factor))
