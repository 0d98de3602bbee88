"""AC quality without truth: remnants at events found in the sensor difference, and the
stability of daily refits (magcal.report.ac_quality)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from magcal.ac import events, stability
from magcal.ac.plan import plan_from_json
from magcal.errors import InputError
from magcal.io.csv import write_csv_frame
from magcal.io.jsonio import write_json
from magcal.report import ac_quality as q

U_STEP = np.array([0.6, 0.0, 0.8])
U_SPIKE = np.array([0.0, 1.0, 0.0])


def _disturbed(rng, n=14400):
    """1 Hz, 4 h: a 3 nT step at 5000 s along U_STEP, a 5 nT spike (FWHM 4 s) at 9000 s
    along U_SPIKE, 0.5 nT rms noise between 2000 and 3800 s along x."""
    t = np.arange(float(n))
    dist = np.zeros((n, 3))
    dist[t >= 5000] += 3.0 * U_STEP
    sigma = 4.0 / (2 * np.sqrt(2 * np.log(2)))
    dist += 5.0 * np.exp(-0.5 * ((t - 9000.0) / sigma) ** 2)[:, None] * U_SPIKE
    hf = (t >= 2000) & (t < 3800)
    dist[hf, 0] += rng.normal(0, 0.5, hf.sum())
    amb = np.array([10.0, -20.0, 30.0]) + rng.normal(0, 0.001, (n, 3))
    return t, amb, dist


def test_remnants_of_a_known_step_spike_and_noise(rng):
    t, amb, dist = _disturbed(rng)
    raw, clean = amb + dist, amb + 0.1 * dist
    diff = 3.0 * dist + rng.normal(0, 0.001, dist.shape)   # inboard sees 4x, outboard 1x
    out = events.remnants(raw, clean, diff, t)
    st, sp, hf = out["steps"], out["spikes"], out["hf"]
    assert st["n"] == 1 and sp["n"] == 1
    np.testing.assert_allclose(st["times_s"], [4999.5], atol=1.0)
    np.testing.assert_allclose(sp["times_s"], [9000.0], atol=1.0)
    # ramp: 3 U_STEP raw, 0.3 U_STEP cleaned (ambient noise 0.001 nT)
    np.testing.assert_allclose(st["raw"]["mean_abs_nT"], 3.0 * U_STEP, atol=0.005)
    np.testing.assert_allclose(st["clean"]["mean_abs_nT"], 0.3 * U_STEP, atol=0.005)
    np.testing.assert_allclose(st["raw"]["mean_module_nT"], 3.0, atol=0.005)
    # spike: peak sample at 9000 s exactly, height 5 U_SPIKE raw, 0.5 cleaned
    np.testing.assert_allclose(sp["raw"]["mean_abs_nT"], 5.0 * U_SPIKE, atol=0.005)
    np.testing.assert_allclose(sp["clean"]["mean_abs_nT"], 0.5 * U_SPIKE, atol=0.005)
    # high-frequency class: the disturbed window inside the noisy interval, the cleaned
    # peak-to-peak excess 0.1 of the raw one (linear), nothing on y, z
    assert 2000 <= hf["disturbed_s"][0] and hf["disturbed_s"][1] <= 3800
    assert not (hf["quiet_s"][1] > 2000 and hf["quiet_s"][0] < 3800)
    assert hf["raw_nT"][0] > 1.5          # ~ 4-5 sigma peak-to-peak of 0.5 nT rms noise
    np.testing.assert_allclose(hf["clean_nT"][0], 0.1 * hf["raw_nT"][0], rtol=0.05)
    np.testing.assert_allclose(hf["raw_nT"][1:], 0.0, atol=0.005)


def test_noise_alone_gives_no_events(rng):
    t = np.arange(20000.0)
    d = rng.normal(0, 0.3, (20000, 3))
    assert events.detect_steps(d, t).size == 0
    assert events.detect_spikes(d, t).size == 0


DAY = 86400.0
CADENCE = 20.0


def _three_days(rng, directions):
    """Three days at 20 s; each day the same random disturbance s(t) (2x at 'o', 40x at
    'a') along that day's direction; constant ambient."""
    n_day = int(DAY / CADENCE)
    s = rng.normal(size=n_day)
    amb = np.array([100.0, -20.0, 40.0])
    o = np.concatenate([amb + 2.0 * s[:, None] * u for u in directions])
    a = np.concatenate([amb + 40.0 * s[:, None] * u for u in directions])
    idx = pd.date_range("2019-03-04", periods=3 * n_day, freq=f"{CADENCE:g}s", tz="UTC",
                        name="time")
    frame = pd.DataFrame(np.c_[o, a], index=idx,
                         columns=["o_x", "o_y", "o_z", "a_x", "a_y", "a_z"])
    return frame, s


def _plan(interval=None):
    return {"target": "o", "stages": [{"kind": "reference", "sensors": ["o"], "reference": "a",
                                       "orders": [{"window_s": None, "interval": interval}]}]}


def test_identical_days_have_zero_spread(rng):
    u = np.array([0.0, 0.6, 0.8])
    frame, _ = _three_days(rng, [u, u, u])
    fits = stability.daily_refits(frame, _plan())
    assert [f["day"] for f in fits] == ["2019-03-04", "2019-03-05", "2019-03-06"]
    out = stability.stability(frame, fits)
    row = out["steps"][0]
    np.testing.assert_allclose([row["std_direction_i_deg"], row["std_direction_ij_deg"],
                                row["std_alpha"]], 0.0, atol=1e-6)
    np.testing.assert_allclose(abs(row["mean_alpha"]), 2.0 / 38.0, rtol=1e-9)  # sign: Eq. 24
    np.testing.assert_allclose([out["bmaxdev_nT"], out["bmaxdev_ac_nT"]], 0.0, atol=1e-9)


def test_direction_spread_and_bmaxdev_in_closed_form(rng):
    theta = np.radians(3.0)
    u0 = np.array([0.0, 0.6, 0.8])
    w = np.array([1.0, 0.0, 0.0])
    dirs = [u0, np.cos(theta) * u0 + np.sin(theta) * w, np.cos(theta) * u0 - np.sin(theta) * w]
    frame, s = _three_days(rng, dirs)
    # interval orders keep their time of day: the first 6 h of each day
    start = pd.Timestamp("2019-03-04", tz="UTC").value / 1e9
    fits = stability.daily_refits(frame, _plan([start, start + 6 * 3600.0]))
    out = stability.stability(frame, fits)
    row = out["steps"][0]
    # RMS angle to the axial mean direction u0: sqrt((0 + 3^2 + 3^2) / 3) deg
    np.testing.assert_allclose(row["std_direction_i_deg"], 3.0 * np.sqrt(2.0 / 3.0), rtol=1e-6)
    np.testing.assert_allclose(row["std_alpha"], 0.0, atol=1e-9)
    # day k's matrices remove u_k: on day d data the corrected field is
    # amb + 2 s (u_d - u_k (u_k . u_d)); Bmaxdev is the largest difference of two k
    worst = 0.0
    for d in dirs:
        for k in range(3):
            for m in range(k + 1, 3):
                dk = dirs[k] * (dirs[k] @ d) - dirs[m] * (dirs[m] @ d)
                worst = max(worst, float(np.max(np.abs(2.0 * s[:, None] * dk))))
    np.testing.assert_allclose(out["bmaxdev_nT"], worst, rtol=1e-6)


def test_short_day_left_out_and_one_day_is_an_error(rng):
    u = np.array([0.0, 0.6, 0.8])
    frame, _ = _three_days(rng, [u, u, u])
    short = frame.iloc[: int(1.3 * DAY / CADENCE)]
    fits = stability.daily_refits(short, _plan())
    assert len(fits) == 1
    with pytest.raises(InputError, match="two daily refits"):
        stability.stability(short, fits)


def test_write_ac_quality_product(rng, tmp_path):
    u = np.array([0.0, 0.6, 0.8])
    frame, _ = _three_days(rng, [u, u, u])
    raw_path = tmp_path / "raw.csv.gz"
    write_csv_frame(raw_path, frame)
    from magcal.ac.estimator import PiCoG

    model = PiCoG(plan_from_json(_plan())).fit(frame)
    (tmp_path / "ac").mkdir()
    write_json(tmp_path / "ac" / "PARAMS_x.json", model.to_params())
    write_csv_frame(tmp_path / "ac" / "CLEAN_x.csv.gz", model.transform(frame))
    path = q.write_ac_quality(tmp_path / "ac", raw_path)
    doc = json.loads(path.read_text())
    plan = doc["plans"]["x"]
    assert plan["pair"] == ["a", "o"]
    assert doc["provenance"]["step"] == "ac quality"
    np.testing.assert_allclose(plan["stability"]["bmaxdev_nT"], 0.0, atol=1e-6)


def test_plan_round_trip_keeps_joint_and_band_orders():
    # daily refits must rebuild exactly the plan that was fitted (joint pair, band order)
    from magcal.ac.chain import Order, Plan, Stage
    from magcal.ac.plan import plan_to_dict

    plan = Plan("fgmo", (
        Stage("reference", ("fgmo", "fgmi"), reference="amr1",
              orders=(Order(interval=(10.0, 20.0)),)),
        Stage("pair", ("fgmo", "fgmi"), joint=True, event_half_s=60.0, min_snr=4.0,
              orders=(Order(window_s=100.0), Order(band_hz=(0.16, 0.17))))))
    assert plan_from_json(plan_to_dict(plan)) == plan


def test_joint_steps_report_matrix_spread(rng):
    # a joint pair step has a full 3x3 and no direction/alpha: its spread is the largest
    # std of a matrix element over the refits (sample std of 0, 0.1, 0.2 is 0.1)
    frame, _ = _three_days(rng, [np.array([0.0, 0.6, 0.8])] * 3)
    refits = []
    for day, a in zip(("d1", "d2", "d3"), (0.0, 0.1, 0.2)):
        A = np.eye(3) * 0.5
        A[0, 1] += a
        refits.append({"day": day, "M": {"o": np.eye(3)}, "steps": [
            {"stage": 2, "order": 1, "i": "o", "j": "i", "kind": "joint", "A": A.tolist()}]})
    row = stability.stability(frame, refits)["steps"][0]
    np.testing.assert_allclose(row["std_matrix_max"], 0.1, rtol=1e-12)
