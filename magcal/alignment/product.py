"""The alignment product (ALIGN.json, CONTRACTS §3) built from matched arrays.

:func:`match_frames` pairs two ``time,Hp,He,Hn`` frames on identical times,
:func:`resolve_longitude` and :func:`quiet_from_kp` prepare the optional inputs, and
:func:`align_product` fits (:class:`magcal.alignment.estimator.Aligner`) and returns an
:class:`AlignmentProduct` whose :meth:`~AlignmentProduct.to_json` is the content of
ALIGN.json and whose :meth:`~AlignmentProduct.write` writes it (and the posterior
samples) atomically. The ``magcal align`` verb and the chain runner both call these, so
the product is the same whichever way it is made.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from collections.abc import Iterable

import numpy as np

from magcal.alignment.estimator import Aligner
from magcal.alignment.gls import DEFAULT_NOISE_MODEL
from magcal.alignment.noise import COMPONENTS
from magcal.alignment.result import AlignmentResult
from magcal.alignment.windows import WindowAngles
from magcal.errors import InputError

#: Fewest matched rows (and quiet rows) an alignment is attempted on.
MIN_ROWS = 10

NO_KP_WARNING = ("no --kp given: all samples used; a model reference lacks the storm-time "
                 "field, which can bias the angles in every window alike (see "
                 "window_consistency)")


@dataclasses.dataclass(frozen=True)
class MatchedPair:
    """Data and reference rows at identical times.

    Attributes
    ----------
    times : ndarray of datetime64[ns], shape (n,)
        UTC, without time zone.
    data, ref : ndarray, shape (n, 3)
        Hp, He, Hn (nT); NaN where a file has no value.
    lon_deg : ndarray or None, shape (n,)
        The data's ``lon_deg`` column at those rows, when it has one.
    n_data, n_ref : int
        Rows in each input.
    """

    times: np.ndarray
    data: np.ndarray
    ref: np.ndarray
    lon_deg: np.ndarray | None
    n_data: int
    n_ref: int

    @property
    def matched_rows(self) -> dict:
        """``{"data_rows", "reference_rows", "matched"}`` as ALIGN.json reports them."""
        return {"data_rows": self.n_data, "reference_rows": self.n_ref,
                "matched": int(self.times.size)}


def match_frames(data, ref, *, data_name=None, ref_name=None,
                 min_rows: int = MIN_ROWS) -> MatchedPair:
    """Match two ``Hp, He, Hn`` frames (DatetimeIndex ``time``) on identical times.

    Parameters
    ----------
    data, ref : pandas.DataFrame
        Indexed by time (naive UTC or tz-aware), with columns ``Hp, He, Hn``; ``data`` may
        carry ``lon_deg``.
    data_name, ref_name : str or path-like, optional
        Names used in error messages (the files they came from).
    min_rows : int
        Fewest matched rows with finite Hp, He, Hn in both.

    Returns
    -------
    MatchedPair

    Raises
    ------
    InputError
        A column is missing, no time is common, or fewer than ``min_rows`` rows match.

    Examples
    --------
    >>> import pandas as pd
    >>> idx = pd.date_range("2019-03-01", periods=12, freq="min", name="time")
    >>> a = pd.DataFrame({"Hp": 1.0, "He": 2.0, "Hn": 3.0}, index=idx)
    >>> match_frames(a, a.iloc[1:]).matched_rows
    {'data_rows': 12, 'reference_rows': 11, 'matched': 11}
    """
    for frame, name in ((data, data_name), (ref, ref_name)):
        missing = [c for c in COMPONENTS if c not in frame.columns]
        if missing:
            raise InputError(f"missing column {missing[0]} (need time,Hp,He,Hn)", file=name,
                             column=missing[0])
    common = data.index.intersection(ref.index)
    if common.size == 0:
        raise InputError("no time in common with the data file", file=ref_name, column="time")
    d = data.loc[common, list(COMPONENTS)].to_numpy(dtype=float)
    r = ref.loc[common, list(COMPONENTS)].to_numpy(dtype=float)
    ok = np.isfinite(d).all(axis=1) & np.isfinite(r).all(axis=1)
    if ok.sum() < min_rows:
        raise InputError(f"only {int(ok.sum())} matched rows with finite Hp, He, Hn in both "
                         f"files (need at least {min_rows})", file=data_name)
    naive = common.tz_convert("UTC").tz_localize(None) if common.tz is not None else common
    lon = data.loc[common, "lon_deg"].to_numpy(dtype=float) if "lon_deg" in data else None
    return MatchedPair(times=naive.to_numpy().astype("datetime64[ns]"), data=d, ref=r,
                       lon_deg=lon, n_data=int(data.shape[0]), n_ref=int(ref.shape[0]))


def resolve_longitude(pair: MatchedPair, longitude_deg: float | None = None, *,
                      data_name=None):
    """Longitude for the local-time field: the given value, else the data's column.

    Returns
    -------
    lon_deg : float, ndarray or None
    source : str or None
        ``"--longitude"``, ``"lon_deg column"`` or None.

    Raises
    ------
    InputError
        The ``lon_deg`` column is used and has missing values in matched rows.
    """
    if longitude_deg is not None:
        return float(longitude_deg), "--longitude"
    if pair.lon_deg is None:
        return None, None
    if not np.isfinite(pair.lon_deg).all():
        raise InputError("lon_deg has missing values in matched rows", file=data_name,
                         column="lon_deg")
    return pair.lon_deg, "lon_deg column"


def quiet_from_kp(times, kp, kp_max: float, *, kp_name=None,
                  min_rows: int = MIN_ROWS) -> np.ndarray:
    """Samples with Kp <= ``kp_max`` (the paper's quiet-time selection).

    Parameters
    ----------
    times : ndarray of datetime64[ns]
    kp : Kp series as returned by :func:`magcal.indices.read_kp`
    kp_max : float
    kp_name : str or path-like, optional
        The Kp file, for the error message.

    Raises
    ------
    InputError
        Fewer than ``min_rows`` quiet samples.
    """
    from magcal.indices import kp_at
    from magcal.offsets.estimator import quiet_mask

    quiet = quiet_mask(kp_at(kp, times), kp_max)
    if quiet.sum() < min_rows:
        raise InputError(f"only {int(quiet.sum())} matched rows with Kp <= {kp_max:g}",
                         file=kp_name)
    return quiet


@dataclasses.dataclass(frozen=True)
class AlignSettings:
    """Settings of an alignment product (every one is recorded in its provenance).

    Attributes
    ----------
    fit_offset, fit_scale : bool
        Fit a constant offset (default) and a common scale with the rotation.
    mcmc : bool
        Sample the posterior with emcee.
    seed : int
        Seed of the generator used when :func:`align_product` gets no ``rng``.
    max_steps : int
        Sampler step limit.
    window_days : "auto", float or None
        Windows of the consistency check (0 or None disables).
    lt_harmonics : "auto" or int
        Local-time harmonics fitted as nuisance.
    max_angle_deg : float
        Physically sensible range of an angle (see
        :mod:`magcal.alignment.determinability`).
    noise_model : str
        ``ou+ou+white`` (default), ``ou`` or ``ou+white``
        (:func:`magcal.alignment.gls.fit_alignment`).
    """

    fit_offset: bool = True
    fit_scale: bool = False
    mcmc: bool = False
    seed: int = 0
    max_steps: int = 40000
    window_days: object = "auto"
    lt_harmonics: object = "auto"
    max_angle_deg: float = 45.0
    noise_model: str = DEFAULT_NOISE_MODEL

    def aligner(self, rng: np.random.Generator | None) -> Aligner:
        """The estimator these settings describe."""
        return Aligner(fit_offset=self.fit_offset, fit_scale=self.fit_scale, mcmc=self.mcmc,
                       rng=rng, max_steps=self.max_steps, lt_harmonics=self.lt_harmonics,
                       window_days=None if self.window_days in (0, 0.0, None)
                       else self.window_days, max_angle_deg=self.max_angle_deg,
                       noise_model=self.noise_model)


@dataclasses.dataclass(frozen=True)
class AlignmentProduct:
    """Everything ALIGN.json holds, with the fitted objects behind it.

    Attributes
    ----------
    result : AlignmentResult
        Reported result (warnings and determinability included).
    closed_form : AlignmentResult
    windows : WindowAngles or None
    lt_harmonics : int
    matched_rows, selection, longitude, provenance : dict
    settings : AlignSettings
    """

    result: AlignmentResult
    closed_form: AlignmentResult
    windows: WindowAngles | None
    lt_harmonics: int
    matched_rows: dict
    selection: dict
    longitude: dict
    provenance: dict
    settings: AlignSettings

    @property
    def determinable(self) -> bool:
        """Whether the data determined the rotation."""
        return self.result.determinable

    @property
    def reason(self) -> str | None:
        """Why the rotation is not determinable (None when it is)."""
        det = self.result.determinability
        return None if det is None else det.reason

    def to_json(self, samples_file: str | None = None) -> dict:
        """ALIGN.json content: CONTRACTS §3 keys first, then diagnostics.

        ``samples_file`` names the posterior samples side file in ``mcmc.samples_file``.
        """
        payload = self.result.to_json()
        if self.settings.mcmc and self.result.method != "emcee":
            payload.update(converged=False, autocorr_steps=None)
            payload["mcmc"] = {"run": False, "message": "posterior not sampled: "
                               + (self.reason or "no rotation fitted")}
        payload["matched_rows"] = dict(self.matched_rows)
        payload["selection"] = dict(self.selection)
        payload["lt_harmonics"] = self.lt_harmonics
        payload["longitude"] = dict(self.longitude)
        if self.settings.mcmc:
            payload["closed_form"] = {k: v for k, v in self.closed_form.to_json().items()
                                      if k in ("angles_deg", "std_deg", "ci95_deg", "method")}
        if self.windows is not None:
            payload["windows"] = _windows_json(self.windows, self.result)
        payload["provenance"] = self.provenance
        if samples_file is not None and self.result.samples is not None:
            payload["mcmc"]["samples_file"] = samples_file
        return payload

    def write(self, path: str | os.PathLike) -> Path:
        """Write ALIGN.json (and, after sampling, ``<stem>.samples.csv.gz``) atomically."""
        from magcal.io.jsonio import write_json

        if self.result.samples is None:
            return write_json(path, self.to_json())
        samples = samples_path_for(path)
        payload = self.to_json(samples_file=samples.name)
        write_samples(samples, self.result)
        try:
            return write_json(path, payload)
        except BaseException:
            samples.unlink(missing_ok=True)  # no half product: samples without ALIGN.json
            raise


def _windows_json(win: WindowAngles, result: AlignmentResult) -> dict:
    out = {k: v for k, v in win.to_json().items() if k not in ("schema_version",
                                                                "magcal_version")}
    if result.determinable:
        out["paper_style"] = {c: f"{a:.2f} ({s:.2f})" for c, a, s
                              in zip(COMPONENTS, result.angles_deg, win.spread_deg)}
    else:
        out["paper_style"] = {c: "not determinable" for c in COMPONENTS}
    out["paper_style_meaning"] = (
        "angle of the whole record (standard deviation of the window angles), as "
        "the SOSMAG paper quotes 1.7 (4.0), -0.5 (1.4), -0.5 (1.9) deg")
    return out


def align_product(times, data_hpen, ref_hpen, *, lon_deg=None, lon_source=None, quiet=None,
                  selection=None, settings: AlignSettings = AlignSettings(),
                  rng: np.random.Generator | None = None,
                  inputs: Iterable[str | os.PathLike] = (),
                  matched_rows: dict | None = None) -> AlignmentProduct:
    """Fit the rotation of ``data_hpen`` against ``ref_hpen`` and build ALIGN.json.

    Parameters
    ----------
    times : ndarray of datetime64[ns], shape (n,)
    data_hpen, ref_hpen : array_like, shape (n, 3)
        Matched Hp, He, Hn (nT), e.g. from :func:`match_frames`.
    lon_deg : float or array_like, optional
        East longitude (scalar or per sample) for the local-time field.
    lon_source : str, optional
        Where the longitude came from (reported).
    quiet : array_like of bool, shape (n,), optional
        Samples to use (e.g. :func:`quiet_from_kp`); the others are left out.
    selection : dict, optional
        How ``quiet`` was chosen (e.g. ``{"kp_file": ..., "kp_max": 1.0}``); reported
        with the rows used.
    settings : AlignSettings
    rng : numpy.random.Generator, optional
        For the sampler; default ``numpy.random.default_rng(settings.seed)``.
    inputs : iterable of path-like
        Input files, listed by SHA-256 in the provenance.
    matched_rows : dict, optional
        Row counts of the matching (:attr:`MatchedPair.matched_rows`).

    Returns
    -------
    AlignmentProduct
        ``result.determinable`` is False (angles NaN, ``reason`` set) when the data
        cannot determine the rotation (:mod:`magcal.alignment.determinability`).
    """
    from magcal.provenance import make_provenance

    d = np.asarray(data_hpen, dtype=float)
    n = d.shape[0]
    sel = {"kp_file": None, "kp_max": None, "used_rows": n}
    if quiet is not None:
        q = np.asarray(quiet, dtype=bool)
        d = np.where(q[:, None], d, np.nan)
        sel = {"kp_file": None, "kp_max": None, **(selection or {}),
               "used_rows": int(q.sum()), "quiet_fraction": float(q.mean())}
    rng = np.random.default_rng(settings.seed) if rng is None else rng
    aligner = settings.aligner(rng).fit(times, d, ref_hpen, lon_deg=lon_deg)
    result = aligner.result_
    if quiet is None:
        result = dataclasses.replace(result, warnings=result.warnings + (NO_KP_WARNING,))
    scalar_lon = lon_deg is not None and np.ndim(lon_deg) == 0
    parameters = {**dataclasses.asdict(settings),
                  "longitude": float(lon_deg) if scalar_lon else None,
                  "kp_max": sel.get("kp_max")}
    return AlignmentProduct(
        result=result, closed_form=aligner.closed_form_, windows=aligner.windows_,
        lt_harmonics=int(aligner.lt_harmonics_),
        matched_rows=dict(matched_rows or {"matched": n}), selection=sel,
        longitude={"source": lon_source,
                   "lon_deg": None if lon_deg is None else float(np.median(lon_deg))},
        provenance=make_provenance("align", parameters, inputs=inputs), settings=settings)


def samples_path_for(output) -> Path:
    """Side file of the posterior samples: ``ALIGN.json`` -> ``ALIGN.samples.csv.gz``."""
    out = Path(output)
    return out.with_name(out.stem + ".samples.csv.gz")


def write_samples(path, result: AlignmentResult) -> None:
    """Posterior samples (angles in degrees, as named in ``mcmc.sample_names``), atomically."""
    import pandas as pd

    from magcal.io.atomic import atomic_path

    names = [n.replace("w_", "angle_deg_") for n in result.mcmc["sample_names"]]
    frame = pd.DataFrame(result.samples, columns=names)
    with atomic_path(path) as tmp:
        frame.to_csv(tmp, index=False, float_format="%.6g", compression="gzip")
