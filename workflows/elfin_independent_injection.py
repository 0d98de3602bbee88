"""An independent check of what the ELFIN-A calibration keeps of natural signals.

Natural magnetic signals, given in GEI, are written into the raw FGS counts of
ELFIN-A on 2022-01-12 (``../shared/real-data/elfin``, ELFIN SOC, PI V. Angelopoulos,
UCLA: "Open Data for Scientific Use"); the injected day is calibrated with the
``magcal run`` command line, as a user would, and compared with the clean day:

* ``recovered = B_GEI(injected) - B_GEI(clean)`` on the zone's rows used in both runs;
* gain ``g = <recovered, s> / <s, s>`` (sums over samples and the 3 components), kept
  energy ``g |g|``, distortion ``sqrt(sum |recovered - g s|^2 / sum |s|^2)``;
* what the injected run's ``spin/ELFIN_CAL.json`` states about the signal
  (``level_steps.intervals``, ``pulses_b.pulses``) and whether the stated errors cover
  the injected truth (pulse along B: 100 nT; sheet: its share along the spin axis, the
  axis the step is stated along, ``300 * ew.axis``, -300 nT on this day: the spin axis
  is the orbit normal's opposite).

Signals (one kind per run, in zones 1, 4, 7, 10 at once, each centred mid-zone):
``gauss_ew`` (200 nT, 40 s FWHM, along the orbit normal ``ew``, the unit vector of
r x v), ``gauss_along`` (200 nT, 40 s FWHM, across B in the orbit plane: the unit
vector of ``ew x B``, on 2022-01-12 within 7-16 deg of minus the along-track direction),
``sheet_ew`` (300 nT tanh step, 10-90 % rise 20 s, lasting to the zone end, along
``ew``), ``pulse_b`` (100 nT, 90 s FWHM, along B) and ``wave_2hz`` (5 nT 2 Hz sine under
a 10 s Hann window, along ``ew``); ``--sign -1`` injects them all with the opposite
polarity. Two more kinds validate the injection itself: ``wave_2hz_along`` and
``wave_2hz_b``, the same wave across B in the orbit plane and along B (a 2 Hz field is
far above what the calibration fits, so it must come back whole in every direction).

How the counts are injected (built here from the delivered files only): for each
sample the rotation body -> GEI comes from TRIAD on two vector pairs,

1. the spin axis: in GEI from the state file's attitude (``ela_att_gei``, interpolated);
   in the body frame of the zone's ``coupling`` (JSON ``zones``, body field
   ``coupling @ counts + offsets_nT``) as measured from the data: the body z row is
   regressed on the clean product's spin-axis component with a tilt that changes along
   the zone (piecewise-linear in time, knots every ``--knot`` s), because the delivered
   ``coupling`` is one matrix per zone while the product's axis turns within it; the
   nominal body z axis is reported alongside (sanity check a);
2. the field: body field from the counts, GEI field of the clean CLI product.

A GEI signal dB then enters the counts as ``inverse(coupling) @ R^T @ dB``, rounded to
integer counts. Sanity checks printed: (a) the per-zone RMS of
``R (coupling @ counts + offsets_nT) - B_GEI(clean)``, nominal and measured axis (with
the measured axis, what remains is the spin-plane magnitude difference between the
zone's one linear matrix and the product's drifting gains and offsets: the direction
about the axis is matched by construction, and the validation waves test the rest);
(b) the unchanged counts written by the CDF writer of ``elfin_messy.py`` and run
through the CLI reproduce the clean product (max |dB|), so recovered signals are not
run-to-run noise.

Why it is independent: nothing is imported from ``magcal`` (neither
``magcal.missions.elfin`` nor its injection study ``workflows/elfin_preservation.py``);
the calibration is reached only through ``python -m magcal run`` in a subprocess, with a
configuration written here, and the geometry is rebuilt from the product files
(``calibrated/elfin_calibrated.csv``, ``spin/ELFIN_CAL.json``) and the raw CDFs.

Run from the repository root (about a minute per CLI run; 7 runs: clean, unchanged
copy, 5 signals)::

    python workflows/elfin_independent_injection.py /tmp/elfin-indep
    python workflows/elfin_independent_injection.py /tmp/elfin-indep --signals pulse_b \\
        --zones 1,4,7,10
    python workflows/elfin_independent_injection.py /tmp/elfin-indep-neg --sign -1 \\
        --signals gauss_ew,gauss_along,sheet_ew,pulse_b

Set ``PYTHONPATH`` to the library copy to be tested; the subprocess inherits it and
runs in ``OUTDIR/runs`` (so the repository's own ``magcal`` folder does not shadow it;
the library path used is printed). The
injected CDFs, configurations, CLI outputs and ``independent_injection.json`` (all the
numbers) are written to OUTDIR, never into the repository. No randomness.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DATA = HERE.parent.parent / "shared" / "real-data" / "elfin"
FGS, STATE = "ela_l1_fgs_20220112_v01.cdf", "ela_l1_state_defn_20220112_v01.cdf"
SIGNALS = ("gauss_ew", "gauss_along", "sheet_ew", "pulse_b", "wave_2hz")
# validation of the injection itself: a 2 Hz wave is far above anything the calibration
# fits, so it must come back at gain 1 along every direction the signals use
VALIDATION = ("wave_2hz_along", "wave_2hz_b")
SHEET_NT, PULSE_NT = 300.0, 100.0
CLAIMS = {  # the library's own study (elfin_preservation.py --no-held --both-signs,
    # quartic gain drift, 2026-11-30): zone medians, kept energy % (distortion %)
    "gauss_ew": (101, 5), "gauss_along": (104, 7), "sheet_ew": (108, 9),
    "pulse_b": (96, 7), "wave_2hz": (100, 0)}
CLAIMS_OPPOSITE = {  # the same with the opposite polarity
    "gauss_ew": (99, 6), "gauss_along": (94, 7), "sheet_ew": (67, 9),
    "pulse_b": (103, 4), "wave_2hz": (100, 0)}


# ----------------------------------------------------------------------------- I/O
def read_fgs(path: Path):
    """Read an ELFIN FGS file.

    Parameters
    ----------
    path : Path
        CDF with ``ela_fgs`` (n, 3) counts and ``ela_fgs_time`` (TT2000).

    Returns
    -------
    times : ndarray of int64
        TT2000 nanoseconds.
    counts : ndarray of int64, shape (n, 3)
        Raw counts of b1, b2, b3.
    """
    import cdflib

    cdf = cdflib.CDF(str(path))
    times = np.asarray(cdf.varget("ela_fgs_time"), dtype=np.int64)
    counts = np.asarray(cdf.varget("ela_fgs"), dtype=np.int64).reshape(-1, 3)
    return times, counts


def read_state(path: Path):
    """Read position, velocity and spin-axis attitude (GEI) from the state file.

    Parameters
    ----------
    path : Path
        ELFIN ``state_defn`` CDF.

    Returns
    -------
    dict
        ``t_pos`` (datetime64[ns]), ``pos`` (km), ``vel`` (km/s), ``t_att``,
        ``att`` (unit spin axis).
    """
    import cdflib

    cdf = cdflib.CDF(str(path))
    to_dt = cdflib.cdfepoch.to_datetime
    return {"t_pos": np.asarray(to_dt(cdf.varget("ela_state_time")), "datetime64[ns]"),
            "pos": np.asarray(cdf.varget("ela_pos_gei"), float),
            "vel": np.asarray(cdf.varget("ela_vel_gei"), float),
            "t_att": np.asarray(to_dt(cdf.varget("ela_att_time")), "datetime64[ns]"),
            "att": np.asarray(cdf.varget("ela_att_gei"), float)}


def read_product(outdir: Path):
    """Read a CLI product: calibrated CSV and the ELFIN calibration JSON.

    Parameters
    ----------
    outdir : Path
        The ``-o`` folder of a ``magcal run``.

    Returns
    -------
    dict
        ``time`` (datetime64[ns]), ``zone`` (int), ``used`` (bool), ``B`` (n, 3) GEI nT,
        ``cal`` (the JSON as a dict).
    """
    import pandas as pd

    df = pd.read_csv(outdir / "calibrated" / "elfin_calibrated.csv")
    cal = json.loads((outdir / "spin" / "ELFIN_CAL.json").read_text())
    return {"time": pd.to_datetime(df["time"]).to_numpy("datetime64[ns]"),
            "zone": df["zone"].to_numpy().astype(int),
            "used": df["used"].to_numpy() == 1,
            "B": df[["bx_gei", "by_gei", "bz_gei"]].to_numpy(float),
            "cal": cal}


# ----------------------------------------------------------------------------- CLI
def cli_command(cwd: Path) -> list[str]:
    """The ``magcal`` command: ``python -m magcal`` if importable as such, else the entry point.

    Parameters
    ----------
    cwd : Path
        Folder the CLI runs in (outside the repository: ``python -m`` puts the working
        folder first on ``sys.path``, before ``PYTHONPATH``).

    Returns
    -------
    list of str
    """
    probe = subprocess.run([sys.executable, "-c", "import importlib.util, sys; "
                            "sys.exit(importlib.util.find_spec('magcal.__main__') is None)"],
                           capture_output=True, text=True, cwd=cwd)
    if probe.returncode == 0:
        return [sys.executable, "-m", "magcal"]
    exe = shutil.which("magcal")
    if exe is None:
        sys.exit("neither `python -m magcal` nor a `magcal` command is available")
    return [exe]


def write_config(path: Path, fgs: Path, state: Path, pipeline=()) -> None:
    """Write a ``magcal run`` configuration for one FGS file (the default pipeline, or
    with the ``[spin.pipeline]`` lines ``pipeline``).

    Parameters
    ----------
    path : Path
        TOML to write.
    fgs, state : Path
        FGS counts file and the (real) state file.
    pipeline : sequence of str
        ``KEY = VALUE`` lines (TOML) of ``[spin.pipeline]``, e.g. ``gain_drift_degree = 5``.
    """
    table = "\n[spin.pipeline]\n" + "".join(f"{line}\n" for line in pipeline) \
        if pipeline else ""
    path.write_text(
        "# independent injection check (workflows/elfin_independent_injection.py)\n"
        f"[input]\nfiles = [\"{fgs.resolve()}\"]\n\n"
        "[spin]\nunits = \"counts\"\nreference = \"igrf\"\n"
        f"state = \"{state.resolve()}\"\n" + table)


def run_cli(cmd: list[str], config: Path, outdir: Path) -> float:
    """Run ``magcal run CONFIG -o OUTDIR`` (one at a time, one worker, OMP 1 thread).

    Parameters
    ----------
    cmd : list of str
        From :func:`cli_command`.
    config : Path
        Configuration.
    outdir : Path
        Fresh output folder (an old one is removed first, so nothing is reused); the
        command runs in its parent folder, so that a ``magcal`` package in the caller's
        working folder cannot shadow the library on ``PYTHONPATH``.

    Returns
    -------
    float
        Wall time in seconds.
    """
    if outdir.exists():
        shutil.rmtree(outdir)
    env = dict(os.environ, OMP_NUM_THREADS="1")
    t0 = time.time()
    proc = subprocess.run([*cmd, "run", str(config), "-o", str(outdir), "--workers", "1",
                           "--quiet"], capture_output=True, text=True, env=env,
                          cwd=outdir.parent)
    (outdir.parent / f"{outdir.name}.log").write_text(proc.stdout + proc.stderr)
    if proc.returncode != 0:
        sys.exit(f"magcal run failed ({proc.returncode}) for {config}:\n{proc.stderr[-2000:]}")
    return time.time() - t0


# ----------------------------------------------------------------------- geometry
def unit(v: np.ndarray) -> np.ndarray:
    """Row-wise unit vectors.

    Parameters
    ----------
    v : ndarray, shape (n, 3)

    Returns
    -------
    ndarray, shape (n, 3)
    """
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def interp_vectors(t: np.ndarray, tk: np.ndarray, vk: np.ndarray) -> np.ndarray:
    """Linear interpolation of vectors in time.

    Parameters
    ----------
    t, tk : ndarray of datetime64[ns]
        Target and knot times.
    vk : ndarray, shape (m, 3)

    Returns
    -------
    ndarray, shape (n, 3)
    """
    x = (t - tk[0]) / np.timedelta64(1, "s")
    xk = (tk - tk[0]) / np.timedelta64(1, "s")
    return np.column_stack([np.interp(x, xk, vk[:, j]) for j in range(3)])


def triad(a1: np.ndarray, a2: np.ndarray, b1: np.ndarray, b2: np.ndarray) -> np.ndarray:
    """TRIAD rotations R (n, 3, 3) with R a1 = b1 exactly and R a2 in the plane of b1, b2.

    Parameters
    ----------
    a1, a2 : ndarray, shape (n, 3)
        Primary and secondary vectors in the source frame (body).
    b1, b2 : ndarray, shape (n, 3)
        The same vectors in the target frame (GEI).

    Returns
    -------
    ndarray, shape (n, 3, 3)
        Rotations source -> target.
    """
    def basis(v1, v2):
        e1 = unit(v1)
        e2 = unit(np.cross(v1, v2))
        return np.stack([e1, e2, np.cross(e1, e2)], axis=-1)  # columns

    return basis(b1, b2) @ np.transpose(basis(a1, a2), (0, 2, 1))


def hat_basis(x: np.ndarray, knot_s: float) -> np.ndarray:
    """Piecewise-linear (hat) functions of x with equally spaced knots over its span.

    Parameters
    ----------
    x : ndarray
        Times in s.
    knot_s : float
        Knot spacing in s.

    Returns
    -------
    ndarray, shape (n, k)
    """
    n_k = max(2, int(np.ceil((x.max() - x.min()) / knot_s)) + 1)
    knots = np.linspace(x.min(), x.max(), n_k)
    h = knots[1] - knots[0]
    return np.clip(1 - np.abs(x[:, None] - knots[None, :]) / h, 0, None)


def body_axis(bb: np.ndarray, b_axis: np.ndarray, x: np.ndarray, fit: np.ndarray,
              knot_s: float) -> tuple[np.ndarray, float]:
    """Spin axis in the body frame of the zone's coupling, measured along the zone.

    The body z component is regressed as ``bb_z - b_axis = alpha(x) bb_x + beta(x) bb_y
    + c(x)`` (hat functions in time), so the spin axis in the body frame is
    ``unit(-alpha, -beta, 1)``.

    Parameters
    ----------
    bb : ndarray, shape (n, 3)
        Body field ``coupling @ counts + offsets_nT``.
    b_axis : ndarray, shape (n,)
        Spin-axis component of the clean product's GEI field.
    x : ndarray, shape (n,)
        Time in s.
    fit : ndarray of bool
        Rows to fit on (used in the clean product).
    knot_s : float
        Knot spacing.

    Returns
    -------
    axis : ndarray, shape (n, 3)
        Unit spin axis in the body frame.
    rms : float
        RMS of the regression residual (nT) on the fitted rows.
    """
    h = hat_basis(x, knot_s)
    a = np.hstack([h * bb[:, :1], h * bb[:, 1:2], h])
    d = bb[:, 2] - b_axis
    coef, *_ = np.linalg.lstsq(a[fit], d[fit], rcond=None)
    k = h.shape[1]
    alpha, beta = h @ coef[:k], h @ coef[k:2 * k]
    rms = float(np.sqrt(np.mean((d - a @ coef)[fit] ** 2)))
    return unit(np.column_stack([-alpha, -beta, np.ones_like(alpha)])), rms


def zone_geometry(k: int, counts: np.ndarray, times: np.ndarray, clean: dict,
                  state: dict, knot_s: float) -> dict:
    """Everything needed to inject into zone k, and sanity check (a) for it.

    Parameters
    ----------
    k : int
        Zone index (JSON ``zones`` order, CSV ``zone`` column).
    counts : ndarray, shape (n, 3)
        Raw counts of the day.
    times : ndarray of datetime64[ns]
        Sample times (UTC) of the day.
    clean : dict
        From :func:`read_product` on the clean run.
    state : dict
        From :func:`read_state`.
    knot_s : float
        Knot spacing of the measured body spin axis.

    Returns
    -------
    dict
        ``rows`` (indices of the zone), ``x`` (s from zone middle), ``R`` (n, 3, 3),
        ``cinv`` (inverse coupling), ``ew``, ``b`` (unit vectors), ``check`` (RMS nT).
    """
    z = clean["cal"]["zones"][k]
    coupling = np.asarray(z["coupling"], float)
    off = np.asarray(z["offsets_nT"], float)
    rows = np.flatnonzero(clean["zone"] == k)
    t = times[rows]
    mid = np.datetime64(z["start"], "ns") + (np.datetime64(z["end"], "ns")
                                             - np.datetime64(z["start"], "ns")) / 2
    x = (t - mid) / np.timedelta64(1, "s")
    bb = counts[rows].astype(float) @ coupling.T + off
    b_gei = clean["B"][rows]
    axis_gei = unit(interp_vectors(t, state["t_att"], state["att"]))
    used = clean["used"][rows]
    axis_body, reg_rms = body_axis(bb, np.sum(b_gei * axis_gei, 1), x, used, knot_s)
    z_body = np.tile([0.0, 0.0, 1.0], (len(rows), 1))
    check = {"regression_rms_nT": reg_rms,
             "offsets_consistent_nT": float(np.abs(off + coupling @ np.asarray(
                 z["offsets_counts"], float)).max())}
    rot = {}
    for name, ab in (("nominal_z", z_body), ("measured_axis", axis_body)):
        r = triad(ab, bb, axis_gei, b_gei)
        err = np.einsum("nij,nj->ni", r, bb) - b_gei
        check[f"rms_{name}_nT"] = float(np.sqrt(np.mean(np.sum(err[used] ** 2, 1))))
        rot[name] = r
    check["max_axis_tilt_deg"] = float(np.degrees(np.arccos(np.clip(axis_body[:, 2], -1, 1))).max())
    check["B_rms_nT"] = float(np.sqrt(np.mean(np.sum(b_gei[used] ** 2, 1))))
    ew = unit(np.cross(interp_vectors(t, state["t_pos"], state["pos"]),
                       interp_vectors(t, state["t_pos"], state["vel"])))
    return {"rows": rows, "x": x, "R": rot["measured_axis"], "cinv": np.linalg.inv(coupling),
            "ew": ew, "b": unit(b_gei), "axis_gei": axis_gei, "check": check,
            "x_end": (np.datetime64(z["end"], "ns") - mid) / np.timedelta64(1, "s")}


# ------------------------------------------------------------------------ signals
def gaussian(x: np.ndarray, height: float, fwhm: float) -> np.ndarray:
    """Gaussian of given height and full width at half maximum, centred at x = 0.

    Parameters
    ----------
    x : ndarray
        Time from the centre, s.
    height, fwhm : float
        nT and s.

    Returns
    -------
    ndarray
    """
    return height * np.exp(-4 * np.log(2) * (x / fwhm) ** 2)


def sheet(x: np.ndarray, height: float, rise_s: float) -> np.ndarray:
    """Current-sheet crossing ``height * (1 + tanh(x / tau)) / 2`` with a 10-90 % rise.

    Parameters
    ----------
    x : ndarray
        Time from the crossing, s.
    height : float
        Step, nT.
    rise_s : float
        10-90 % rise time, s (``tau = rise / (2 atanh 0.8)``).

    Returns
    -------
    ndarray
    """
    tau = rise_s / (2 * np.arctanh(0.8))
    return height * 0.5 * (1 + np.tanh(x / tau))


def hann_wave(x: np.ndarray, amp: float, freq: float, window_s: float) -> np.ndarray:
    """Sine of given frequency under a Hann window of given length, centred at x = 0.

    Parameters
    ----------
    x : ndarray
        Time from the centre, s.
    amp, freq, window_s : float
        nT, Hz, s.

    Returns
    -------
    ndarray
    """
    w = np.where(np.abs(x) <= window_s / 2, 0.5 * (1 + np.cos(2 * np.pi * x / window_s)), 0.0)
    return amp * np.sin(2 * np.pi * freq * x) * w


def signal_gei(kind: str, geo: dict) -> np.ndarray:
    """The GEI signal (n, 3) in nT of one kind over a zone's rows.

    Parameters
    ----------
    kind : str
        One of :data:`SIGNALS` or :data:`VALIDATION`.
    geo : dict
        From :func:`zone_geometry`.

    Returns
    -------
    ndarray, shape (n, 3)
    """
    x, ew, b = geo["x"], geo["ew"], geo["b"]
    along = unit(np.cross(ew, b))
    if kind == "gauss_ew":
        return gaussian(x, 200, 40)[:, None] * ew
    if kind == "gauss_along":
        return gaussian(x, 200, 40)[:, None] * along
    if kind == "sheet_ew":
        return np.where(x <= geo["x_end"], sheet(x, SHEET_NT, 20), 0.0)[:, None] * ew
    if kind == "pulse_b":
        return gaussian(x, PULSE_NT, 90)[:, None] * b
    if kind == "wave_2hz":
        return hann_wave(x, 5, 2, 10)[:, None] * ew
    if kind == "wave_2hz_along":
        return hann_wave(x, 5, 2, 10)[:, None] * along
    if kind == "wave_2hz_b":
        return hann_wave(x, 5, 2, 10)[:, None] * b
    raise ValueError(f"unknown signal {kind!r}")


def inject(counts: np.ndarray, kind: str, geos: dict,
           sign: float = 1.0) -> tuple[np.ndarray, dict]:
    """Counts with the signal in every zone of geos, and the GEI signals per zone.

    Parameters
    ----------
    counts : ndarray, shape (n, 3)
        Raw counts.
    kind : str
        Signal kind.
    geos : dict
        Zone -> :func:`zone_geometry`.
    sign : float
        +1 for the signals as defined, -1 for the opposite polarity.

    Returns
    -------
    counts : ndarray of int64
        Injected counts (rounded).
    signals : dict
        Zone -> GEI signal (n_zone, 3).
    """
    out = counts.astype(np.int64).copy()
    signals = {}
    for k, g in geos.items():
        s = sign * signal_gei(kind, g)
        body = np.einsum("nji,nj->ni", g["R"], s)  # R^T s
        out[g["rows"]] += np.rint(body @ g["cinv"].T).astype(np.int64)
        signals[k] = s
    if np.abs(out).max() >= 2**31 - 1:
        raise ValueError("injected counts do not fit the file's INT4")
    return out, signals


# ---------------------------------------------------------------------- measures
def measure(clean: dict, run: dict, geo: dict, s: np.ndarray) -> dict:
    """Gain, kept energy and distortion of the recovered signal in one zone.

    Parameters
    ----------
    clean, run : dict
        From :func:`read_product`.
    geo : dict
        From :func:`zone_geometry`.
    s : ndarray, shape (n_zone, 3)
        Injected GEI signal on the zone's rows.

    Returns
    -------
    dict
        ``gain``, ``kept`` (g |g|), ``distortion``, ``n`` rows compared, ``n_zone``.
    """
    rows = geo["rows"]
    ok = clean["used"][rows] & run["used"][rows]
    r = (run["B"] - clean["B"])[rows][ok]
    s = s[ok]
    ss = float(np.sum(s * s))
    g = float(np.sum(r * s)) / ss
    dist = float(np.sqrt(np.sum((r - g * s) ** 2) / ss))
    return {"gain": g, "kept": g * abs(g), "distortion": dist, "n": int(ok.sum()),
            "n_zone": int(rows.size)}


def stated(cal: dict) -> dict:
    """What the product's JSON states about level steps and pulses along B.

    Parameters
    ----------
    cal : dict
        ``ELFIN_CAL.json``.

    Returns
    -------
    dict
        ``level_steps`` and ``pulses_b`` entries (all zones, the JSON's own fields).
    """
    lv = cal.get("level_steps", {}).get("intervals", []) or []
    pu = cal.get("pulses_b", {}).get("pulses", []) or []
    return {"level_steps": lv, "pulses_b": pu}


def coverage(value: float, err: float, truth: float) -> str:
    """Text: stated value +- error against the truth, covered at 1 and 2 sigma or not.

    Parameters
    ----------
    value, err, truth : float

    Returns
    -------
    str
    """
    if err is None or not np.isfinite(err) or err <= 0:
        return f"{value:.1f} (no error stated) vs {truth:.0f}"
    z = (value - truth) / err
    tag = "covered 1s" if abs(z) <= 1 else ("covered 2s" if abs(z) <= 2 else "NOT covered")
    return f"{value:.1f} +- {err:.1f} vs {truth:.0f}: {z:+.1f} sigma, {tag}"


# -------------------------------------------------------------------------- main
def main(argv=None) -> int:
    """Command line: build the injections, run the CLI, print and write the numbers."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", type=Path, help="folder for the injected files, runs and JSON")
    p.add_argument("--signals", default=",".join(SIGNALS + VALIDATION),
                   help="comma-separated kinds (default: all of "
                        f"{','.join(SIGNALS + VALIDATION)}; the last two validate the "
                        "injection)")
    p.add_argument("--zones", default="1,4,7,10", help="zones to inject into (0..11)")
    p.add_argument("--data", type=Path, default=DATA, help="folder of the real ELFIN files")
    p.add_argument("--sign", type=float, default=1.0, choices=(1.0, -1.0),
                   help="polarity of every signal (-1: the opposite field; the kept share "
                        "of a pulse across B depends on it)")
    p.add_argument("--knot", type=float, default=20.0,
                   help="knot spacing (s) of the measured body spin axis")
    p.add_argument("--pipeline", nargs="*", default=[], metavar="KEY=VALUE",
                   help="[spin.pipeline] settings of every run (TOML values), e.g. "
                        "gain_drift_degree=5; default: the delivered pipeline")
    args = p.parse_args(argv)
    pipeline = []
    for item in args.pipeline:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            p.error(f"--pipeline wants KEY=VALUE, got {item!r}")
        pipeline.append(f"{key.strip()} = {value.strip()}")
    kinds = [s for s in args.signals.split(",") if s]
    bad = [s for s in kinds if s not in SIGNALS + VALIDATION]
    if bad:
        p.error(f"unknown signals {bad}; known: {SIGNALS + VALIDATION}")
    zones = [int(z) for z in args.zones.split(",") if z]
    fgs, state_path = args.data / FGS, args.data / STATE
    for f in (fgs, state_path):
        if not f.is_file():
            sys.exit(f"real ELFIN data not found: {f} (expected beside the repository in "
                     "../shared/real-data/elfin, or give --data)")
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    runs = out / "runs"
    runs.mkdir(exist_ok=True)
    cmd = cli_command(runs)
    lib = subprocess.run([sys.executable, "-c", "import magcal; print(magcal.__file__)"],
                         capture_output=True, text=True, cwd=runs).stdout.strip()
    print(f"CLI: {' '.join(cmd)} run ...  (magcal from {lib})")

    # the plain CDF writer of the messy copy (cdflib only, nothing from magcal)
    sys.path.insert(0, str(HERE))
    from elfin_messy import write_fgs

    times_tt, counts = read_fgs(fgs)
    import cdflib
    times = np.asarray(cdflib.cdfepoch.to_datetime(times_tt), "datetime64[ns]")
    state = read_state(state_path)
    result = {"cli": cmd, "magcal": lib, "zones": zones, "signals": kinds, "sign": args.sign,
              "pipeline": pipeline,
              "claims_kept_distortion_percent": CLAIMS if args.sign > 0 else CLAIMS_OPPOSITE}

    cfg = out / "clean.toml"
    write_config(cfg, fgs, state_path, pipeline)
    wall = run_cli(cmd, cfg, runs / "clean")
    clean = read_product(runs / "clean")
    print(f"clean run: {wall:.0f} s")
    # the product repairs a few time tags (by ~10 ms): rows still match one to one
    if len(clean["time"]) != len(times) or np.any(
            np.abs((clean["time"] - times) / np.timedelta64(1, "ms")) > 50):
        sys.exit("the calibrated CSV rows do not match the FGS samples one to one")
    n_zones = len(clean["cal"]["zones"])
    if any(z < 0 or z >= n_zones for z in zones):
        sys.exit(f"zones must be in 0..{n_zones - 1}")

    geos = {k: zone_geometry(k, counts, times, clean, state, args.knot) for k in range(n_zones)}
    print("\n(a) R (coupling @ counts + offsets_nT) - B_GEI(clean), RMS |dB| nT on used rows")
    print("zone  |B|rms  nominal_z  measured_axis  axis_reg_rms  max_tilt_deg  ew.axis")
    for k, g in geos.items():
        c = g["check"]
        c["ew_dot_axis_median"] = float(np.median(np.sum(g["ew"] * g["axis_gei"], 1)))
        print(f"{k:4d}  {c['B_rms_nT']:6.0f}  {c['rms_nominal_z_nT']:9.1f}  "
              f"{c['rms_measured_axis_nT']:13.1f}  {c['regression_rms_nT']:12.1f}  "
              f"{c['max_axis_tilt_deg']:12.2f}  {c['ew_dot_axis_median']:7.3f}")
    result["check_a"] = {k: g["check"] for k, g in geos.items()}

    unchanged = out / "ela_fgs_unchanged.cdf"
    write_fgs(unchanged, times_tt, counts)
    cfg = out / "unchanged.toml"
    write_config(cfg, unchanged, state_path, pipeline)
    wall = run_cli(cmd, cfg, runs / "unchanged")
    same = read_product(runs / "unchanged")
    d = np.abs(same["B"] - clean["B"])
    check_b = {"max_abs_dB_nT": float(np.nanmax(d)), "used_equal": bool(np.all(
        same["used"] == clean["used"])), "wall_s": wall}
    print(f"\n(b) unchanged counts rewritten and re-run: max |dB| = {check_b['max_abs_dB_nT']:.3g}"
          f" nT, used flags equal: {check_b['used_equal']} ({wall:.0f} s)")
    result["check_b"] = check_b

    inj = {k: geos[k] for k in zones}
    result["runs"] = {}
    for kind in kinds:
        new, signals = inject(counts, kind, inj, args.sign)
        path = out / f"ela_fgs_{kind}.cdf"
        write_fgs(path, times_tt, new)
        cfg = out / f"{kind}.toml"
        write_config(cfg, path, state_path, pipeline)
        wall = run_cli(cmd, cfg, runs / kind)
        prod = read_product(runs / kind)
        per = {k: measure(clean, prod, inj[k], signals[k]) for k in zones}
        st = stated(prod["cal"])
        result["runs"][kind] = {"zones": per, "stated": st, "wall_s": wall,
                                "median_kept": float(np.median([v["kept"] for v in per.values()])),
                                "median_distortion": float(np.median(
                                    [v["distortion"] for v in per.values()]))}
        print(f"\n{kind}: run {wall:.0f} s")
        for k, v in per.items():
            print(f"  zone {k:2d}: gain {v['gain']:.3f}  kept {100 * v['kept']:6.1f} %  "
                  f"distortion {100 * v['distortion']:5.1f} %  ({v['n']}/{v['n_zone']} rows)")
        for e in st["level_steps"]:
            line = f"  level step zone {e.get('zone')}: "
            if e.get("zone") in zones and kind == "sheet_ew":
                # the step is stated along the spin axis: the truth is the sheet's share
                g = inj[e["zone"]]
                after = g["x"] > 0
                share = float(np.median(np.sum(g["ew"] * g["axis_gei"], 1)[after]))
                truth = args.sign * SHEET_NT * share
                line += coverage(e.get("step_nT", np.nan), e.get("step_error_nT"), truth)
                trials = e.get("trial_levels_nT") or []
                if trials:
                    line += f"; trials {np.round(trials, 0).tolist()} for |step|"
                e["truth_along_spin_axis_nT"] = truth
            else:
                line += f"{json.dumps({q: e.get(q) for q in ('step_nT', 'step_error_nT')})}"
            print(line)
        for e in st["pulses_b"]:
            line = f"  pulse_b zone {e.get('zone')}: "
            if e.get("zone") in zones and kind == "pulse_b":
                line += coverage(e.get("height_nT", np.nan), e.get("height_error_nT"),
                                 args.sign * PULSE_NT)
                trials = e.get("trial_heights_nT") or []
                if trials:
                    line += f"; trials {np.round(trials, 0).tolist()}"
            else:
                line += f"{json.dumps({q: e.get(q) for q in ('height_nT', 'height_error_nT')})}"
            print(line)
        if not st["level_steps"] and not st["pulses_b"]:
            print("  JSON: no level steps, no pulses_b")
        (out / "independent_injection.json").write_text(json.dumps(result, indent=1, default=float))

    print("\nkept energy % (distortion %) per zone; median; library's claim")
    head = "signal        " + "".join(f"zone {k:<10d}" for k in zones) + "median        claim"
    print(head)
    for kind, r in result["runs"].items():
        cells = "".join(f"{100 * v['kept']:5.0f} ({100 * v['distortion']:3.0f})   "
                        for v in r["zones"].values())
        claims = CLAIMS if args.sign > 0 else CLAIMS_OPPOSITE
        claim = "{:4d} ({:2d})".format(*claims[kind]) if kind in claims else "   - (validation)"
        med = f"{100 * r['median_kept']:5.0f} ({100 * r['median_distortion']:3.0f})"
        print(f"{kind:<14}{cells}{med}   {claim}")
    (out / "independent_injection.json").write_text(json.dumps(result, indent=1, default=float))
    print(f"\nwrote {out / 'independent_injection.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
