"""ELFIN calibration on counts with added instrument noise (magcal.missions.elfin.noise).

Closed forms for the noise itself and for the frames it is carried through; then the
real day (ELFIN-A 2022-01-12, ELFIN SOC, PI V. Angelopoulos, UCLA) with seeded white
plus correlated noise: the product must carry no more noise than was added, its
residuals must stay within the noise-free ones and the noise in quadrature, the
detector must not take noise for a natural field, and the stated bridge error must
still cover an injected pulse.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from conftest import real_data_path
from numpy.testing import assert_allclose

from magcal.errors import InputError
from magcal.missions.elfin.noise import (instrument_noise, noise_gei, noise_transfer,
                                         noisy_counts)

COLS = ["bx_gei", "by_gei", "bz_gei"]


def test_noise_has_the_stated_parts():
    """White std, OU std and the OU's lag correlation exp(-dt / tau), per axis;
    the two parts separate by differencing (white adds 2 w^2 to the lag-1 difference)."""
    t = np.arange(0.0, 20000.0, 0.1)
    n = instrument_noise(t, np.random.default_rng(7), white_nT=2.0, red_nT=5.0,
                         red_tau_s=30.0)
    assert n.shape == (t.size, 3)
    assert_allclose(n.std(axis=0), np.hypot(2.0, 5.0), rtol=0.05)
    # red part: lag 300 samples (30 s), where the white part no longer correlates
    lag = 300
    c = np.mean(n[lag:] * n[:-lag], axis=0) / 25.0
    assert_allclose(c, np.exp(-1.0), atol=0.06)
    # white part: the lag-1 difference has 2 (w^2 + s^2 (1 - phi))
    d = np.diff(n, axis=0).var(axis=0)
    assert_allclose(d, 2 * (4.0 + 25.0 * (1 - np.exp(-0.1 / 30.0))), rtol=0.05)
    with pytest.raises(InputError):
        instrument_noise(t, np.random.default_rng(0), white_nT=1.0, red_nT=1.0, red_tau_s=0.0)


def _fake_calibration(n=400, seed=3):
    """Two zones with known couplings, phases and spin axes."""
    rng = np.random.default_rng(seed)
    zone = np.repeat([0, 1], n // 2)
    phase = np.linspace(0.0, 60.0, n) + rng.uniform(0, 1)
    axis = np.tile([0.3, -0.9, 0.3], (n, 1)) + 0.01 * rng.standard_normal((n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    field = pd.DataFrame({"zone": zone, "phase": phase,
                          **{f"spin_axis_gei_{c}": axis[:, j] for j, c in enumerate("xyz")}})
    couplings = [np.diag([2.0, 3.0, 4.0]) + 0.1 * rng.standard_normal((3, 3))
                 for _ in range(2)]
    zones = [SimpleNamespace(coupling=c) for c in couplings]
    fgs = pd.DataFrame(rng.standard_normal((n, 3)) * 100, columns=["b1", "b2", "b3"])
    return SimpleNamespace(field=field, zones=zones), fgs


def test_noise_in_counts_and_in_gei_agree_with_the_injection_path():
    """Body noise carried to GEI (noise_gei) and injected back as a GEI signal
    (injection.inject_counts) gives the counts noisy_counts makes: the two frame paths
    are each other's inverse. The counts change by C^-1 n per zone."""
    from magcal.missions.elfin.injection import inject_counts

    clean, fgs = _fake_calibration()
    body = np.random.default_rng(1).standard_normal((len(fgs), 3))
    direct = noisy_counts(fgs, clean, body)
    zone = clean.field["zone"].to_numpy()
    gei = noise_gei(clean, body)
    via_gei = inject_counts(fgs, clean, {k: gei[zone == k] for k in (0, 1)})
    assert_allclose(direct.to_numpy(), via_gei.to_numpy(), atol=1e-9)
    change = direct.to_numpy() - fgs.to_numpy()
    assert_allclose(change[zone == 1] @ clean.zones[1].coupling.T, body[zone == 1],
                    atol=1e-9)
    # a rotation: the norm is kept
    assert_allclose(np.linalg.norm(gei, axis=1), np.linalg.norm(body, axis=1), rtol=1e-12)
    with pytest.raises(InputError):
        noisy_counts(fgs.iloc[:10], clean, body)


def test_transfer_closed_forms():
    rng = np.random.default_rng(2)
    n = 1000
    clean = pd.DataFrame(rng.standard_normal((n, 3)) * 1e4, columns=COLS).assign(used=1)
    noise = rng.standard_normal((n, 3)) * 5.0
    passed = clean.assign(**{c: clean[c] + noise[:, j] for j, c in enumerate(COLS)})
    t = noise_transfer(clean, passed, noise)
    assert_allclose([t["transfer"], t["added_rms_nT"]], [1.0, 0.0], atol=1e-9)
    assert_allclose(t["noise_rms_nT"], np.sqrt(np.mean(np.sum(noise ** 2, axis=1))))
    half = clean.assign(**{c: clean[c] + 0.5 * noise[:, j] for j, c in enumerate(COLS)})
    t = noise_transfer(clean, half, noise)
    assert_allclose([t["transfer"], t["added_rms_nT"]], [0.5, 0.5 * t["noise_rms_nT"]])
    # no noise: nothing to compare with
    assert np.isnan(noise_transfer(clean, clean, np.zeros((n, 3)))["transfer"])
    # unused rows do not count
    worse = passed.copy()
    worse.loc[:9, COLS] += 1e6
    worse.loc[:9, "used"] = 0
    assert_allclose(noise_transfer(clean, worse, noise)["transfer"],
                    noise_transfer(clean.iloc[10:], passed.iloc[10:], noise[10:])["transfer"])


@pytest.mark.realdata
@pytest.mark.slow
def test_calibration_carries_no_more_noise_than_was_added():
    """Zones 1 and 7 (each with natural excursions the detector leaves out), white 2 nT
    plus correlated 5 nT (30 s) per body axis, one seed. Truths: the noise added
    (known draw) and the pulses injected on top. Tolerances: the product's change at
    most the noise (transfer <= 1); residuals within the noise-free ones and the noise per component
    in quadrature (5 %); the detector leaves out no more than noise-free plus 5 points;
    40 s pulses across B kept >= 85 % with their error within twice the stated bridge
    error (20 seeds of the 4 default zones, workflows/elfin_noise.py: see README)."""
    from magcal.missions.elfin.files import read_elfin_fgs, read_elfin_state
    from magcal.missions.elfin.injection import select_zones
    from magcal.missions.elfin.noise import noise_trials

    fgs = read_elfin_fgs(real_data_path("elfin", "ela_l1_fgs_20220112_v01.cdf"))
    state = read_elfin_state(real_data_path("elfin", "ela_l1_state_defn_20220112_v01.cdf"))
    passes, kept = noise_trials(select_zones(fgs, (1, 7)), state, seeds=[11],
                                white_nT=2.0, red_nT=5.0, red_tau_s=30.0)
    clean = passes[passes["seed"] < 0].set_index("product")
    noisy = passes[passes["seed"] == 11].set_index("product")
    delivered = noisy.index[-1]
    assert delivered == "+ phase refit"
    # the delivered product; the steps before it are not delivered, and the linear
    # step alone moves by more than the noise where the detector's flags moved
    assert noisy.loc[delivered, "transfer"] <= 1.0, noisy["transfer"]
    per_component = noisy["noise_rms_nT"].iloc[0] / np.sqrt(3.0)
    for m in ("scalar_rms_nT", "vector_rms_nT"):
        bound = np.hypot(clean.loc[delivered, m], per_component)
        assert noisy.loc[delivered, m] <= 1.05 * bound, (m, noisy.loc[delivered, m], bound)
    assert noisy.loc[delivered, "left_out_share"] <= clean.loc[delivered,
                                                               "left_out_share"] + 0.05
    last = kept[kept["product"] == delivered]
    assert len(last) == 4
    assert (last["energy_kept"] >= 0.85).all(), last[["signal", "zone", "energy_kept"]]
    both = last.dropna(subset=["error_rms_nT", "bridge_rms_nT"])
    assert len(both) >= 2
    assert (both["error_rms_nT"] <= 2.0 * both["bridge_rms_nT"]).all()
