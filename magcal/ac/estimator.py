"""Thin estimator around the PiCoG chain, for multi-sensor DataFrames.

Frames follow CONTRACTS §0: a UTC DatetimeIndex and columns ``<sensor>_x/_y/_z`` in one
common frame (nT). Fitting works on a uniform time grid (rows missing from the file
become NaN samples, so scan windows always span ``window_s`` seconds); applying works
row by row.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.ac.chain import ChainResult, Plan, apply_weights, run_chain
from magcal.ac.plan import plan_to_dict
from magcal.errors import InputError
from magcal.io.jsonio import product_dict
from magcal.timeconv import epoch_seconds

COMPONENTS = ("x", "y", "z")


def sensors_in_frame(frame: pd.DataFrame) -> list[str]:
    """Sensor names with all three ``_x/_y/_z`` columns, in column order.

    Examples
    --------
    >>> sensors_in_frame(pd.DataFrame(columns=["a_x", "a_y", "a_z", "b_x", "t"]))
    ['a']
    """
    out = []
    for c in frame.columns:
        if str(c).endswith("_x"):
            name = str(c)[:-2]
            if all(f"{name}_{k}" in frame.columns for k in COMPONENTS) and name not in out:
                out.append(name)
    return out


def sensor_array(frame: pd.DataFrame, sensor: str) -> np.ndarray:
    """``(n, 3)`` float array of one sensor; InputError naming the missing column."""
    cols = [f"{sensor}_{k}" for k in COMPONENTS]
    for c in cols:
        if c not in frame.columns:
            src = frame.attrs.get("source")
            raise InputError(f"sensor {sensor!r} is missing from the input (have: "
                             f"{', '.join(sensors_in_frame(frame)) or 'none'})",
                             file=src, column=c)
    return frame[cols].to_numpy(dtype=float)


def uniform_grid(t_s: np.ndarray, tolerance: float = 0.05):
    """Map sample times onto a uniform grid of the median spacing.

    Returns
    -------
    slots : ndarray of int
        Grid index of each sample.
    n_grid : int
    dt : float
        Grid spacing (s).

    Raises
    ------
    InputError
        Samples further than ``tolerance * dt`` from the grid (irregular sampling).

    Examples
    --------
    >>> uniform_grid(np.array([0.0, 1.0, 2.0, 4.0]))[0].tolist()
    [0, 1, 2, 4]
    """
    t_s = np.asarray(t_s, dtype=float)
    if t_s.size < 2:
        raise InputError("need at least two samples")
    dt = float(np.median(np.diff(t_s)))
    k = np.round((t_s - t_s[0]) / dt).astype(np.int64)
    off = np.abs(t_s - (t_s[0] + k * dt))
    if np.max(off) > tolerance * dt:
        bad = int(np.argmax(off > tolerance * dt))
        raise InputError(f"irregular sampling: sample {bad} is {off[bad]:.3g} s off the "
                         f"{dt:.6g} s grid; resample the input to one cadence")
    return k, int(k[-1]) + 1, dt


class PiCoG:
    """Principal-component gradiometer AC cleaning (Constantinescu et al. 2020).

    Parameters
    ----------
    plan : Plan, optional
        Stages and orders to fit (see :mod:`magcal.ac.plan`). Required unless ``auto``.
    target : str, optional
        Target sensor for ``auto`` (with a plan, the plan's target is used).
    auto : bool
        Let :func:`magcal.ac.auto.auto_plan` choose references, pairs, windows, orders.
    alpha_method : {"decorrelate", "variance"}
    keep_scans : bool
        Keep per-window scan results in ``result_.scans`` (for plots).

    Attributes
    ----------
    result_ : ChainResult
    M_ : dict, G_ : ndarray, steps_ : tuple
    plan_ : Plan (the plan fitted; chosen by auto if ``auto``)
    auto_report_ : dict or None (why each automatic choice was made)

    Examples
    --------
    >>> from magcal.ac.chain import Plan, Stage
    >>> idx = pd.date_range("2019-03-04", periods=600, freq="1s", tz="UTC")
    >>> rng = np.random.default_rng(0); s = rng.normal(size=600)
    >>> df = pd.DataFrame({"o_x": 1 + 2 * s, "o_y": 2.0, "o_z": 3.0,
    ...                    "a_x": 1 + 40 * s, "a_y": 2.0, "a_z": 3.0}, index=idx)
    >>> model = PiCoG(Plan("o", (Stage("reference", ("o",), reference="a"),))).fit(df)
    >>> out = model.transform(df)
    >>> np.allclose(out[["x", "y", "z"]].to_numpy(), [1.0, 2.0, 3.0])
    True
    """

    def __init__(self, plan: Plan | None = None, *, target: str | None = None,
                 auto: bool = False, alpha_method: str = "decorrelate",
                 keep_scans: bool = False):
        self.plan = plan
        self.target = target
        self.auto = auto
        self.alpha_method = alpha_method
        self.keep_scans = keep_scans

    def fit(self, frame: pd.DataFrame) -> "PiCoG":
        """Fit the chain on ``frame`` (all rows; plan intervals select sub-ranges)."""
        if len(frame) < 3:
            raise InputError("need at least 3 samples to fit")
        t_s = epoch_seconds(frame.index)
        slots, n_grid, dt = uniform_grid(t_s)
        grid_t = t_s[0] + dt * np.arange(n_grid)
        names = sensors_in_frame(frame)

        def gridded(sensor):
            out = np.full((n_grid, 3), np.nan)
            out[slots] = sensor_array(frame, sensor)
            return out

        if self.auto:
            from magcal.ac.auto import auto_plan

            target = self.target or (self.plan.target if self.plan else None)
            if target is None:
                raise InputError("--auto needs a target sensor")
            if target not in names:
                sensor_array(frame, target)  # raises naming the column
            data = {s: gridded(s) for s in names}
            plan, report = auto_plan(data, grid_t, target, alpha_method=self.alpha_method)
        else:
            if self.plan is None:
                raise InputError("give a plan or use auto")
            plan, report = self.plan, None
            data = {s: gridded(s) for s in plan.sensors}
        self.plan_ = plan
        self.auto_report_ = report
        self.result_: ChainResult = run_chain(data, grid_t, plan, alpha_method=self.alpha_method,
                                              keep_scans=self.keep_scans)
        self.M_ = self.result_.M
        self.G_ = self.result_.G
        self.steps_ = self.result_.steps
        self.target_ = plan.target
        return self

    def transform(self, frame: pd.DataFrame, *, pure_ac: bool = False) -> pd.DataFrame:
        """Cleaned target ``sum_k M_k B_k`` (+ ``G`` with ``pure_ac``) as ``x, y, z, flag``."""
        return apply_upload(frame, self.M_, self.G_, pure_ac=pure_ac)

    def to_params(self, provenance: dict | None = None) -> dict:
        """PARAMS.json payload (CONTRACTS §1) without the schema keys."""
        res = self.result_
        payload = {
            "target": self.target_,
            "M": {k: np.asarray(v).tolist() for k, v in res.M.items()},
            "G": np.asarray(res.G).tolist(),
            "steps": [s.to_dict() for s in res.steps],
            "identity_error": res.identity_error,
            "alpha_method": self.alpha_method,
            "plan": plan_to_dict(self.plan_),
        }
        if self.auto_report_ is not None:
            payload["auto"] = self.auto_report_
        if provenance is not None:
            payload["provenance"] = provenance
        return payload

    def to_json(self, provenance: dict | None = None) -> dict:
        """The PARAMS.json product (with ``schema_version`` and ``magcal_version``)."""
        return product_dict(self.to_params(provenance))


def apply_upload(frame: pd.DataFrame, M: dict, G=None, *, pure_ac: bool = False) -> pd.DataFrame:
    """Apply upload matrices to a multi-sensor frame.

    Rows where a sensor with a non-zero matrix is missing get NaN and ``flag = 1``;
    good rows have ``flag = 0``.
    """
    data = {k: sensor_array(frame, k) for k in M}
    clean = apply_weights(data, {k: np.asarray(v, dtype=float) for k, v in M.items()})
    if pure_ac:
        if G is None:
            raise InputError("--pure-ac needs the DC offset G in the parameters")
        clean = clean + np.asarray(G, dtype=float)
    bad = ~np.all(np.isfinite(clean), axis=1)
    clean[bad] = np.nan
    out = pd.DataFrame(clean, index=frame.index, columns=list(COMPONENTS))
    out["flag"] = bad.astype(int)
    return out


def params_from_json(doc: dict, *, file=None) -> tuple[dict, np.ndarray | None, str]:
    """(M, G, target) from a PARAMS.json document, validated."""
    for key in ("M", "target"):
        if key not in doc:
            raise InputError(f"missing key {key!r}", file=file)
    M = {}
    for k, v in doc["M"].items():
        arr = np.asarray(v, dtype=float)
        if arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
            raise InputError(f"M[{k!r}] must be a finite 3x3 matrix", file=file)
        M[k] = arr
    if not M:
        raise InputError("M is empty", file=file)
    if np.max(np.abs(sum(M.values()) - np.eye(3))) > 1e-6:
        raise InputError("the M matrices do not sum to the identity (Eq. 33)", file=file)
    G = doc.get("G")
    G = None if G is None else np.asarray(G, dtype=float)
    return M, G, doc["target"]
