"""Instrument noise added to ELFIN counts: does the calibration pass it, or add to it?

The real day carries its own noise; how the calibration behaves on noisier counts
(a worse sensor, a noisier day) is measured by adding seeded noise to the raw counts
and calibrating again. The noise is *instrument* noise: drawn per body axis in nT
(white plus an Ornstein-Uhlenbeck part, the correlated wander of a fluxgate's offset),
fixed in the spinning body, and turned into counts through the inverse of the clean
calibration's coupling (:func:`noisy_counts`). In the despun frame its spin-plane part
therefore sits at the spin frequency, and only its spin-axis part stays slow.

A calibration that does no harm returns the noise at most as it came in: the
product's change ``calibrated(noisy) - calibrated(clean)`` is no larger than the noise
itself (:func:`noise_transfer`; below 1 where the slow fits take part of the offset
wander, which is then removed, not added). :func:`noise_gei` gives the noise in the
product's frame for that comparison.

Examples
--------
>>> import numpy as np
>>> t = np.arange(0.0, 600.0, 0.1)
>>> n = instrument_noise(t, np.random.default_rng(1), white_nT=2.0, red_nT=5.0,
...                      red_tau_s=30.0)
>>> n.shape, bool(abs(n.std() - np.hypot(2.0, 5.0)) < 1.0)
((6000, 3), True)
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from magcal.errors import InputError


def instrument_noise(t_s, rng: np.random.Generator, *, white_nT: float, red_nT: float,
                     red_tau_s: float) -> np.ndarray:
    """Noise (n, 3) in nT per body axis: white plus Ornstein-Uhlenbeck.

    Parameters
    ----------
    t_s : array_like (n,)
        Sample times, s (gaps welcome: the OU part decorrelates over them exactly).
    rng : numpy.random.Generator
    white_nT, red_nT : float
        Standard deviations of the white and the correlated part, nT per axis.
    red_tau_s : float
        Correlation time of the correlated part, s.
    """
    from magcal.alignment.noise import simulate_ou

    t = np.asarray(t_s, dtype=float)
    if white_nT < 0 or red_nT < 0 or red_tau_s <= 0:
        raise InputError("noise needs white_nT >= 0, red_nT >= 0 and red_tau_s > 0 "
                         f"(got {white_nT}, {red_nT}, {red_tau_s})")
    white = rng.standard_normal((t.size, 3)) * white_nT
    red = np.column_stack([simulate_ou(rng, t, red_nT, red_tau_s) for _ in range(3)])
    return white + red


def noisy_counts(fgs: pd.DataFrame, clean, noise_body) -> pd.DataFrame:
    """FGS counts plus body-frame noise (nT) through the inverse of the clean coupling.

    Parameters
    ----------
    fgs : DataFrame
        The counts that ``clean`` was calibrated from (same rows, in order).
    clean : ElfinCalibration
        Its linear calibration (``zones`` with each zone's ``coupling``, nT per count).
    noise_body : array_like (len(fgs), 3)
        :func:`instrument_noise`; rows outside the calibrated zones are left alone.
    """
    from magcal.missions.elfin.injection import add_body_field

    return add_body_field(fgs, clean, noise_body)


def noise_gei(clean, noise_body) -> np.ndarray:
    """Body-frame noise (n, 3) in GEI through the clean spin phase and spin axis: the
    noise as the product would carry it if the calibration passed it unchanged."""
    from magcal.frames.spinning import despin
    from magcal.missions.elfin.phase import despun_basis

    f = clean.field
    noise = np.asarray(noise_body, dtype=float)
    out = np.full(noise.shape, np.nan)
    zone = f["zone"].to_numpy()
    for k in dict.fromkeys(zone.tolist()):
        rows = np.flatnonzero(zone == k)
        z = f.iloc[rows]
        basis = despun_basis(z[[f"spin_axis_gei_{c}" for c in "xyz"]].to_numpy())
        despun = despin(noise[rows], z["phase"].to_numpy())
        out[rows] = np.einsum("nji,nj->ni", basis, despun)
    return out


def noise_transfer(clean_field: pd.DataFrame, noisy_field: pd.DataFrame,
                   noise_in_gei) -> dict:
    """How much of the added noise reached the product, and what else changed.

    Over the samples both products use: ``transfer`` is the RMS of ``|noisy - clean|``
    over the RMS of ``|noise|`` (1: passed unchanged; below 1: part of it taken out;
    above 1: the calibration added to it; NaN without noise), ``added_rms_nT`` the RMS
    of what changed that is not the noise (``|noisy - clean - noise|``),
    ``noise_rms_nT`` the noise's.

    Examples
    --------
    >>> cols = ["bx_gei", "by_gei", "bz_gei"]
    >>> clean = pd.DataFrame(np.zeros((4, 3)), columns=cols).assign(used=1)
    >>> noise = np.array([[3.0, 4.0, 0.0]] * 4)
    >>> half = clean.assign(bx_gei=1.5, by_gei=2.0)
    >>> {k: round(v, 3) for k, v in noise_transfer(clean, half, noise).items()}
    {'transfer': 0.5, 'added_rms_nT': 2.5, 'noise_rms_nT': 5.0}
    """
    cols = ["bx_gei", "by_gei", "bz_gei"]
    used = (clean_field["used"].to_numpy() == 1) & (noisy_field["used"].to_numpy() == 1)
    change = (noisy_field[cols].to_numpy(float) - clean_field[cols].to_numpy(float))[used]
    noise = np.asarray(noise_in_gei, float)[used]
    msq = lambda x: float(np.mean(np.sum(x * x, axis=1)))  # noqa: E731
    return {"transfer": float(np.sqrt(msq(change) / msq(noise))) if msq(noise) > 0
            else np.nan,
            "added_rms_nT": float(np.sqrt(msq(change - noise))),
            "noise_rms_nT": float(np.sqrt(msq(noise)))}


def left_out_share(field: pd.DataFrame) -> float:
    """Share of the used samples that the calibration left out of its fits.

    Examples
    --------
    >>> left_out_share(pd.DataFrame({"used": [1, 1, 1, 0], "fit": [1, 0, 1, 0]}))
    0.3333333333333333
    """
    used = field["used"].to_numpy() == 1
    return float(np.mean(field["fit"].to_numpy()[used] == 0)) if used.any() else np.nan


def noise_trials(fgs: pd.DataFrame, state: pd.DataFrame, settings=None, *, seeds,
                 white_nT: float, red_nT: float, red_tau_s: float,
                 kinds=("gauss_ew", "gauss_along"), centres=(0.3, 0.7),
                 progress=None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The calibration on counts with seeded instrument noise, one draw per seed.

    For each seed: noise (:func:`instrument_noise`) is added to the counts and the day
    calibrated again; every product's change is compared with the noise
    (:func:`noise_transfer`, against the noise-free day). Then each signal of ``kinds``
    (:data:`~magcal.missions.elfin.injection.SIGNALS`) is injected into the *noisy*
    counts, centred at a fraction of each zone drawn from ``centres``, and what the
    product keeps is measured against the noisy day
    (:func:`~magcal.missions.elfin.injection.preservation`, with the stated bridge error
    ``bridge_rms_nT`` next to the signal's own ``error_rms_nT`` where it was left out).

    Parameters
    ----------
    fgs, state : DataFrame
        The day (or the zones of it to use: :func:`~magcal.missions.elfin.injection.select_zones`).
    settings : ElfinSettings, optional
        Default: the delivered ones (bridge trials run on the injected runs only).
    seeds : iterable of int
        One :class:`numpy.random.Generator` per seed draws the noise and the centres.
    white_nT, red_nT, red_tau_s : float
        The noise (:func:`instrument_noise`).
    kinds : sequence of str
        Signals injected, one run each per seed (empty: the noise alone).
    centres : (float, float)
        Range of the signal's centre as a fraction of the zone's used span.
    progress : callable, optional
        Called with one line per seed.

    Returns
    -------
    passes : DataFrame
        Per seed and product: :func:`noise_transfer`, the zone medians of the scores
        (nT) and, for the delivered product, ``left_out_share`` (median over zones of
        :func:`left_out_share`: the detector's flags); the noise-free day as seed -1.
    kept : DataFrame
        :func:`~magcal.missions.elfin.injection.preservation` rows with ``seed`` and
        ``centre``.
    """
    from dataclasses import replace

    from magcal.missions.elfin import injection as inj
    from magcal.missions.elfin.pipeline import ElfinSettings, calibrate_elfin_day

    s = settings or ElfinSettings()
    quiet = replace(s, bridge_trials=0)
    clean = calibrate_elfin_day(fgs, state, quiet, diagnostics=False)
    t = (fgs.index.asi8 - fgs.index.asi8[0]) / 1e9

    def scores(day, seed, transfer):
        rows = []
        for name, med in day.medians().items():
            row = {"seed": seed, "product": name, **transfer.get(name, {}),
                   **{k: v for k, v in med.items() if k in (
                       "scalar_rms_nT", "scalar_fast_nT", "vector_rms_nT")}}
            if name == day.delivered:
                f = day.calibration.field
                row["left_out_share"] = float(np.median(
                    [left_out_share(f[f["zone"] == k]) for k in f["zone"].unique()]))
            rows.append(row)
        return rows

    passes, kept = scores(clean, -1, {}), []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        noise = instrument_noise(t, rng, white_nT=white_nT, red_nT=red_nT,
                                 red_tau_s=red_tau_s)
        counts = noisy_counts(fgs, clean.linear, noise)
        noisy = calibrate_elfin_day(counts, state, quiet, diagnostics=False)
        if noisy.calibration.skipped or len(noisy.calibration.field) != len(fgs):
            raise InputError(f"seed {seed}: the noisy day skipped zones "
                             f"{[z.zone for z in noisy.calibration.skipped]}")
        in_gei = noise_gei(clean.linear, noise)
        transfer = {name: noise_transfer(clean.products[name].field, p.field, in_gei)
                    for name, p in noisy.products.items()}
        passes += scores(noisy, seed, transfer)
        f = noisy.linear.field
        for kind in kinds:
            where = {k: float(rng.uniform(*centres)) for k in dict.fromkeys(f["zone"])}
            signals = {k: inj.signal_gei(kind, f[f["zone"] == k], state, centre=c)
                       for k, c in where.items()}
            day = calibrate_elfin_day(inj.inject_counts(counts, noisy.linear, signals),
                                      state, s, diagnostics=False)
            tab = inj.preservation(noisy, day, signals, kind)
            tab["seed"], tab["centre"] = seed, [where[k] for k in tab["zone"]]
            kept.append(tab)
        if progress is not None:
            row = passes[-1]
            progress(f"seed {seed}: delivered product carries {row['transfer']:.2f} of the "
                     f"noise ({row['noise_rms_nT']:.1f} nT RMS), vector residual "
                     f"{row['vector_rms_nT']:.1f} nT")
    return pd.DataFrame(passes), (pd.concat(kept, ignore_index=True) if kept
                                  else pd.DataFrame())
