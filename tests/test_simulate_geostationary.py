"""The geostationary multi-sensor simulator against its own truth and against closed forms."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from magcal.errors import InputError
from magcal.frames.hpen import geo_to_hpen, osrf_to_hpen
from magcal.simulate import ambient as amb
from magcal.simulate.disturbers import Disturber
from magcal.simulate.geostationary import (GeostationaryConfig, GeostationaryResult,
                                           hpen_to_osrf, simulate_geostationary)
from magcal.simulate.profiles import SquareWaveProfile, ToneProfile
from magcal.simulate.sensors import Sensor, ShadowPhase

SEED = 20190304


@pytest.fixture(scope="module")
def day() -> GeostationaryResult:
    """The default GK-2A-like day at 1 s (shared: about 1 s to build)."""
    return simulate_geostationary(rng=np.random.default_rng(SEED))


def _short(**kw) -> GeostationaryConfig:
    kw.setdefault("duration_s", 1800.0)
    kw.setdefault("ambient_model", "dipole")
    return GeostationaryConfig(**kw)


# ------------------------------------------------------------------ shape and time

def test_default_day_layout(day):
    m = day.measurements
    assert m.shape == (86400, 12)
    assert list(m.columns) == [f"{s}_{c}" for s in ("fgmo", "fgmi", "amr1", "amr2")
                               for c in "xyz"]
    assert m.index.name == "time" and str(m.index.tz) == "UTC"
    assert m.index[0] == pd.Timestamp("2019-03-04T00:00:00", tz="UTC")
    assert m.index[-1] == pd.Timestamp("2019-03-04T23:59:59", tz="UTC")
    assert np.all(np.diff(m.index.asi8) == 1_000_000_000)
    assert np.isfinite(m.to_numpy()).all()
    assert m.to_numpy().dtype == np.float64


@pytest.mark.parametrize("duration_s,cadence_s,n", [(600.0, 0.0625, 9600), (3600.0, 4.0, 900),
                                                    (100.0, 1.0, 100)])
def test_cadence_and_duration(duration_s, cadence_s, n):
    cfg = _short(duration_s=duration_s, cadence_s=cadence_s, start="2020-01-01T12:00:00Z")
    res = simulate_geostationary(cfg, rng=np.random.default_rng(1))
    assert len(res.times) == n and len(res.measurements) == n
    dt = np.diff(res.times.asi8) / 1e9
    assert_allclose(dt, cadence_s, rtol=0, atol=1e-9)
    assert res.times[0] == pd.Timestamp("2020-01-01T12:00:00", tz="UTC")
    for arr in (res.truth.ambient, res.truth.noise["fgmo"], res.truth.offsets["amr1"]):
        assert arr.shape == (n, 3)


# ------------------------------------------------------------------ decomposition

def test_measurements_are_the_sum_of_the_truth_terms(day):
    t = day.truth
    for s in t.sensor_names:
        R = t.misalignment[s]
        field = t.ambient.copy()
        for d in t.patterns:
            # profile coefficients times the fixed pattern, in the common frame
            true_d = t.profiles[d] @ t.patterns[d][s]
            assert_allclose(t.disturbances[d][s], true_d @ R.T, rtol=0, atol=1e-9)
            field += true_d
        expected = field @ R.T + t.offsets[s] + t.noise[s]
        assert_allclose(day.sensor(s), expected, rtol=0, atol=1e-9)
        assert_allclose(day.sensor(s), t.clean(s) + t.disturbance(s) + t.noise[s],
                        rtol=0, atol=1e-9)
        assert_allclose(t.clean(s), t.ambient @ R.T + t.offsets[s], rtol=0, atol=1e-12)


def test_misalignment_rotations_match_the_configured_angles(day):
    for sensor in day.truth.config.sensors:
        R = day.truth.misalignment[sensor.name]
        assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
        assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)
        angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
        assert_allclose(angle, np.linalg.norm(sensor.misalignment_deg), rtol=1e-9)


def test_noise_levels_and_independence(day):
    t = day.truth
    assert_allclose(t.noise["fgmo"].std(axis=0), 0.03, rtol=0.02)
    assert_allclose(t.noise["amr1"].std(axis=0), 0.6, rtol=0.02)
    c = np.corrcoef(t.noise["fgmo"][:, 0], t.noise["fgmi"][:, 0])[0, 1]
    assert abs(c) < 0.02


# ------------------------------------------------------------------ reproducibility

def test_same_seed_same_output_different_seed_different():
    cfg = _short(duration_s=900.0)
    a = simulate_geostationary(cfg, rng=np.random.default_rng(7))
    b = simulate_geostationary(cfg, rng=np.random.default_rng(7))
    c = simulate_geostationary(cfg, rng=np.random.default_rng(8))
    assert_array_equal(a.measurements.to_numpy(), b.measurements.to_numpy())
    assert_array_equal(a.truth.ambient, b.truth.ambient)
    assert not np.array_equal(a.measurements.to_numpy(), c.measurements.to_numpy())
    diff = np.abs(a.measurements.to_numpy() - c.measurements.to_numpy())
    assert diff.max() > 0.1


def test_rng_is_required():
    with pytest.raises(TypeError):
        simulate_geostationary(_short())
    with pytest.raises(InputError, match="Generator"):
        simulate_geostationary(_short(), rng=42)


# ------------------------------------------------------------------ ambient field

def test_ambient_frames_and_magnitude(day):
    t = day.truth
    assert_allclose(osrf_to_hpen(t.ambient), t.ambient_hpen, rtol=0, atol=0)
    assert_allclose(hpen_to_osrf(t.ambient_hpen), t.ambient, rtol=0, atol=0)
    mag = np.linalg.norm(t.ambient_hpen, axis=1)
    assert 50.0 < mag.min() and mag.max() < 160.0  # GEO, quiet to moderate
    assert 70.0 < np.median(t.ambient_hpen[:, 0]) < 130.0  # Hp dominant, northward


@pytest.mark.skipif(not amb.t89_available(), reason="IRBEM (spacepy) not available")
def test_t89_ambient_passes_through_the_model_at_whole_minutes():
    from magcal.models.irbem import field_geo

    cfg = _short(duration_s=3 * 3600.0, ulf=False, substorm=False, ambient_model="T89",
                 kp=[1.0, 2.0 + 1 / 3], start="2019-03-04T10:30:00")
    res = simulate_geostationary(cfg, rng=np.random.default_rng(3))
    assert res.truth.ambient_model == "T89"
    minutes = np.arange(0, len(res.times), 60)
    times = res.times[minutes]
    kp = np.where(times < pd.Timestamp("2019-03-04T12:00", tz="UTC"), 1.0, 2.0 + 1 / 3)
    pos = amb.geo_position_re(128.2, len(times))
    expected = geo_to_hpen(field_geo(times, pos, "T89", {"Kp": kp}), 128.2, 0.0)
    assert_allclose(res.truth.ambient_hpen[minutes], expected, rtol=0, atol=1e-9)
    # between the minutes the spline stays smooth (no Kp step here inside a minute)
    jumps = np.abs(np.diff(res.truth.ambient_hpen, axis=0)).max()
    assert jumps < 1.0


def test_dipole_placeholder_at_noon_and_midnight():
    # no activity terms: ambient = tilted dipole + placeholder external field
    cfg = _short(duration_s=86400.0, cadence_s=60.0, ulf=False, substorm=False, kp=0.0,
                 disturbers=(), shadow=None)
    res = simulate_geostationary(cfg, rng=np.random.default_rng(0))
    lt = amb.local_time_h(np.arange(1440) * 60.0, res.times[0], 128.2)
    internal = geo_to_hpen(amb.dipole_geo(amb.geo_position_re(128.2, 1)), 128.2, 0.0)[0]
    noon, midnight = np.argmin(np.abs(lt - 12.0)), np.argmin(np.abs(lt - 0.0))
    assert_allclose(res.truth.ambient_hpen[noon], internal + [15.0, 0.0, 0.0], atol=0.05)
    assert_allclose(res.truth.ambient_hpen[midnight], internal + [-5.0, -6.0, 0.0], atol=0.05)


def test_substorm_dip_depth_and_switches():
    base = dict(duration_s=6 * 3600.0, start="2019-03-04T11:00:00", cadence_s=2.0)
    with_ss = simulate_geostationary(_short(**base, substorm_depth_nT=30.0),
                                     rng=np.random.default_rng(5))
    without = simulate_geostationary(_short(**base, substorm=False),
                                     rng=np.random.default_rng(5))
    onset = with_ss.truth.events["substorm"]
    assert len(onset) == 1
    lt = amb.local_time_h((onset - with_ss.times[0]).total_seconds().to_numpy(),
                          with_ss.times[0], 128.2)
    assert abs(lt[0] - 22.5) <= 0.5 + 1e-9
    dip = with_ss.truth.ambient_hpen - without.truth.ambient_hpen
    assert_allclose(dip[:, 0].min(), -30.0, atol=0.1)  # Hp dip of the configured depth
    i_on = with_ss.times.searchsorted(onset[0])
    assert_allclose(dip[i_on - 1, 1], -15.0, atol=0.01)  # He: half, before the turbulence
    turb = dip[i_on + 1:i_on + 301, 1:] - dip[i_on + 1:i_on + 301, 1:].mean(axis=0)
    assert 1.0 < turb.std() < 4.0  # 3 nT rms turbulence after the onset (band-limited)
    before = with_ss.times < onset[0] - pd.Timedelta(hours=1)
    assert_allclose(dip[before], 0.0, atol=1e-12)
    # ULF: both runs share their ULF waves (independent random streams)
    no_ulf = simulate_geostationary(_short(**base, substorm=False, ulf=False),
                                    rng=np.random.default_rng(5))
    ulf = without.truth.ambient_hpen - no_ulf.truth.ambient_hpen
    assert 0.3 < np.abs(ulf).max() < 3 * 2.0


# ------------------------------------------------------------------ disturbers in the day

def test_gk2a_disturbance_sizes_follow_the_papers(day):
    t = day.truth
    amp = {d: {s: np.linalg.norm(p[0]) for s, p in per.items()} for d, per in t.patterns.items()}
    # midnight disturbance: 34 nT at FGMO, about 40x at AMR1, 5x at AMR2 (PiCoG §4.1)
    assert_allclose(amp["midnight"]["fgmo"], 34.0, rtol=1e-6)
    assert 30 < amp["midnight"]["amr1"] / amp["midnight"]["fgmo"] < 55
    assert 3.5 < amp["midnight"]["amr2"] / amp["midnight"]["fgmo"] < 6.5
    # spikes 4.9 nT at FGMO, 13.8 at FGMI (ratio 2.8) - dipole geometry gives ~2.45
    assert_allclose(amp["spikes"]["fgmo"], 4.9, rtol=1e-6)
    assert 2.0 < amp["spikes"]["fgmi"] / amp["spikes"]["fgmo"] < 3.0
    # the midnight step as seen in the measured fgmo series
    ev = t.events["midnight"]
    i_up = day.times.get_loc(ev[0].floor("s"))
    before = np.median(t.disturbances["midnight"]["fgmo"][i_up - 90:i_up - 30], axis=0)
    after = np.median(t.disturbances["midnight"]["fgmo"][i_up + 30:i_up + 90], axis=0)
    assert_allclose(np.linalg.norm(after - before), 34.0, rtol=0.01)
    assert ev[0] == pd.Timestamp("2019-03-04T15:15:12", tz="UTC")
    # spikes every 10 minutes
    assert_allclose(np.median(np.diff(t.events["spikes"].asi8)) / 1e9, 600.0, atol=2.0)


def test_linear_disturbers_are_rank_one_and_wheel_is_not(day):
    t = day.truth
    for d in ("midnight", "spikes", "steps", "hf_noise", "tone_6s"):
        for s in ("fgmo", "fgmi"):
            ev = np.linalg.eigvalsh(np.cov(t.disturbances[d][s].T))
            assert ev[1] / ev[2] < 1e-12, (d, s)
    for s in ("fgmo", "fgmi", "amr1"):
        ev = np.linalg.eigvalsh(np.cov(t.disturbances["reaction_wheel"][s].T))
        assert ev[1] / ev[2] > 0.05, s


def test_same_direction_up_to_sign_at_two_sensors_without_misalignment():
    sensors = (Sensor("a", (1.0, 0.0, 0.0), noise_nT=0.0),
               Sensor("b", (2.0, 0.0, 0.0), noise_nT=0.0))
    coil = Disturber("coil", (0.0, 0.0, 0.0), (0.4, 0.0, 0.0), ToneProfile(30.0))
    res = simulate_geostationary(_short(sensors=sensors, disturbers=(coil,), shadow=None),
                                 rng=np.random.default_rng(0))
    ba = res.truth.disturbances["coil"]["a"]
    bb = res.truth.disturbances["coil"]["b"]
    assert_allclose(ba, 8.0 * bb, rtol=1e-12, atol=1e-14)  # (2/1)^3, collinear
    # the common frame is the body frame rotated to the OSRF: x_body -> z_osrf
    assert_allclose(np.abs(ba[:, :2]).max(), 0.0, atol=1e-14)
    assert_allclose(res.truth.patterns["coil"]["a"][0], [0.0, 0.0, 2 * 100 * 0.4], atol=1e-12)
    diff = res.sensor("a") - res.sensor("b")
    assert_allclose(diff, ba - bb, atol=1e-9)  # ambient cancels without misalignment


# ------------------------------------------------------------------ temperature offsets

def test_boom_shadow_temperature_and_offset_oscillations(day):
    t = day.truth
    temp = t.temperature_C["fgmo"]
    assert_allclose(temp.max(), 30.0, atol=1e-9)
    drop = -90.0 - 30.0
    assert_allclose(temp.min(), 30.0 + drop * (1 - np.exp(-2.0)), atol=0.1)
    assert_allclose(t.temperature_C["amr1"], 20.0)
    # shadow starts at local time 5.0 h: 20:27:12 UT the previous day -> 20:27:12 UT
    i_cold = int(np.argmin(temp))
    assert_allclose(day.times[i_cold].hour + day.times[i_cold].minute / 60, 21.45, atol=0.02)
    # AMR offsets are constant; boom offsets vary by the drift + SOO (a few nT)
    assert_allclose(np.ptp(t.offsets["amr1"], axis=0), 0.0, atol=1e-12)
    ptp = np.ptp(t.offsets["fgmo"], axis=0)
    assert 1.0 < ptp.max() < 6.0
    sunlit = slice(3 * 3600, 19 * 3600)  # long after yesterday's shadow, before today's
    assert_allclose(t.offsets["fgmo"][sunlit], np.broadcast_to([4.0, -3.0, 6.0], (16 * 3600, 3)),
                    atol=1e-6)
    # the oscillations peak at the shadow entry, where the cooling is fastest
    soo = t.offsets["fgmo"] - np.array([4.0, -3.0, 6.0])
    entry = day.times.get_loc(pd.Timestamp("2019-03-04T20:27:12", tz="UTC"))
    assert np.abs(soo[entry - 5:entry]).max() < 1e-6
    assert 0.5 < np.abs(soo[entry:entry + 300]).max() < 2.5


def test_shadow_switch_off_gives_constant_offsets():
    res = simulate_geostationary(_short(shadow=None), rng=np.random.default_rng(2))
    for s, off in res.truth.offsets.items():
        assert_allclose(np.ptp(off, axis=0), 0.0, atol=1e-12)


# ------------------------------------------------------------------ custom layouts and kp

def test_custom_layout_three_booms_two_far_apart_disturbers():
    sensors = tuple(Sensor(f"s{i}", (1.5 + 0.4 * i, 0.2, -0.1), noise_nT=0.01)
                    for i in range(3)) + (Sensor("body", (0.5, 0.9, 0.0), noise_nT=0.2),)
    disturbers = (
        Disturber("heater", (0.0, -1.0, 1.5), (0.3, 0.3, 0.0), SquareWaveProfile(600.0, 0.4)),
        Disturber("coil", (0.2, 1.0, -1.5), (0.1, -0.2, -0.4), ToneProfile(45.0)),
        Disturber("quad", (-0.5, 0.0, 0.0), (0.0, 0.0, 1.0), ToneProfile(20.0),
                  kind="quadrupole", separation_m=(0.0, 0.0, 0.2)),
    )
    res = simulate_geostationary(_short(sensors=sensors, disturbers=disturbers, kp=2.0),
                                 rng=np.random.default_rng(4))
    assert res.measurements.shape == (1800, 12)
    assert set(res.truth.disturbances) == {"heater", "coil", "quad"}
    assert set(res.truth.disturbances["coil"]) == {"s0", "s1", "s2", "body"}
    assert_allclose(res.truth.kp.to_numpy(), 2.0)
    # non-orthogonal polarisation directions at s2 (angle well away from 90 deg)
    u = res.truth.patterns["heater"]["s2"][0]
    v = res.truth.patterns["coil"]["s2"][0]
    angle = np.degrees(np.arccos(abs(u @ v) / np.linalg.norm(u) / np.linalg.norm(v)))
    assert_allclose(angle, 42.37, atol=0.01)  # from the dipole formula, rotation-invariant


def test_kp_inputs():
    series = pd.Series([1.0, 3.0], index=pd.to_datetime(["2019-03-04T00:00", "2019-03-04T03:00"]))
    res = simulate_geostationary(_short(duration_s=6 * 3600.0, cadence_s=10.0, kp=series),
                                 rng=np.random.default_rng(0))
    assert_allclose(res.truth.kp.to_numpy(), [1.0, 3.0])
    assert str(res.truth.kp.index.tz) == "UTC"
    with pytest.raises(InputError, match="3-hour bin"):
        simulate_geostationary(_short(duration_s=7 * 3600.0, kp=[1.0, 2.0]),
                               rng=np.random.default_rng(0))
    with pytest.raises(InputError, match="after the simulation start"):
        simulate_geostationary(_short(kp=series[1:]), rng=np.random.default_rng(0))
    quiet = amb.quiet_kp_series("2019-03-04", "2019-03-10T23:59", np.random.default_rng(9))
    assert len(quiet) == 56
    assert_allclose(quiet.to_numpy() * 3, np.round(quiet.to_numpy() * 3), atol=1e-12)
    assert 0.5 < quiet.mean() < 2.5


def test_config_validation():
    with pytest.raises(InputError, match="unique"):
        simulate_geostationary(_short(sensors=(Sensor("a", (2, 0, 0)), Sensor("a", (3, 0, 0)))),
                               rng=np.random.default_rng(0))
    with pytest.raises(InputError, match="rotation"):
        simulate_geostationary(_short(body_to_common=((1, 0, 0), (0, 1, 0), (0, 0, -1))),
                               rng=np.random.default_rng(0))
    with pytest.raises(InputError, match="two samples"):
        simulate_geostationary(_short(duration_s=1.0), rng=np.random.default_rng(0))
    with pytest.raises(InputError, match="sensor name"):
        Sensor("FGM", (0, 0, 0))
    with pytest.raises(InputError, match="coil"):
        simulate_geostationary(
            _short(sensors=(Sensor("a", (1.0, 0.0, 0.0)),),
                   disturbers=(Disturber("coil", (1.0, 0.0, 0.0), (1, 0, 0), ToneProfile()),)),
            rng=np.random.default_rng(0))


def test_to_json_summary(day):
    js = day.to_json()
    assert js["schema_version"] == 1 and "magcal_version" in js
    assert js["n_samples"] == 86400
    assert js["ambient_model"] == day.truth.ambient_model
    assert_allclose(js["offset_mean_nT"]["amr1"], [40.0, -25.0, 60.0], atol=1e-9)
    assert js["provenance"]["step"] == "simulate geostationary"
    assert {d["name"] for d in js["config"]["disturbers"]} >= {"midnight", "reaction_wheel"}
    import json
    json.dumps(js, allow_nan=False)


def test_gk2a_like_equals_default_and_replace():
    a = GeostationaryConfig.gk2a_like()
    b = GeostationaryConfig()
    assert [s.name for s in a.sensors] == [s.name for s in b.sensors]
    assert a.disturbers == b.disturbers
    c = a.replace(ulf=False, shadow=ShadowPhase(duration_s=1800.0))
    assert c.ulf is False and c.shadow.duration_s == 1800.0 and a.ulf is True


def test_measurements_round_trip_through_the_contract_csv(tmp_path):
    from magcal.io.csv import read_csv_frame, write_csv_frame

    res = simulate_geostationary(_short(duration_s=120.0, cadence_s=0.5),
                                 rng=np.random.default_rng(6))
    path = tmp_path / "sim.csv"
    write_csv_frame(path, res.measurements)
    back = read_csv_frame(path, required=list(res.measurements.columns))
    assert list(back.columns) == list(res.measurements.columns)
    assert_array_equal(back.index.asi8, res.times.asi8)
    # the writer's default format keeps 0.1 pT: half a unit of the last digit
    assert_allclose(back.to_numpy(), res.measurements.to_numpy(), rtol=0, atol=5.0001e-5)
