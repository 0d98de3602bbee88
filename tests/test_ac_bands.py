"""Issue 22: band-selective PiCoG, never worse than raw; issue 20 part 3 for PiCoG: a few
glitches that pass quality control do not turn the fit.

Truth: synthetic records with an injected disturber (its direction and scaling known in
closed form) and the partner sensor's injected noise; the real records' own raw target
(the product may not exceed it by more than 10 % in any band) and, for the MST
benchmark, its ambient truth ``Bam_*``.
"""

import json

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from magcal.ac.bandcheck import band_check
from magcal.ac.bands import deliver
from magcal.ac.chain import Order, Plan, Stage
from magcal.ac.estimator import PiCoG
from magcal.cli import main

U = np.array([0.0, 0.6, 0.8])
#: first-order reference stage with ambient-free directions (the ambient varies here)
PLAN = Plan("o", (Stage("reference", ("o",), reference="a",
                        orders=(Order(direction="coherent"),)),))


def _tone_pair(rng, n=32768, fs=128.0):
    """Target ``o`` with a 35 Hz tone along U; reference ``a`` sees it 3x and carries
    0.2 nT white noise (the target 0.01 nT): a first-order reference stage removes the
    tone with ``A = 0.5 U U^T`` and injects ``0.5 * 0.2 = 0.1`` nT along U elsewhere."""
    t = np.arange(n) / fs
    tone = np.sin(2 * np.pi * 35.0 * t)
    amb = np.array([100.0, -20.0, 40.0]) + 0.3 * np.sin(2 * np.pi * t / 60)[:, None]
    o = amb + tone[:, None] * U + 0.01 * rng.normal(size=(n, 3))
    a = amb + 3 * tone[:, None] * U + 0.2 * rng.normal(size=(n, 3))
    idx = pd.date_range("2020-01-01", periods=n, freq=pd.Timedelta(seconds=1 / fs), tz="UTC")
    frame = pd.DataFrame(np.hstack([o, a]), index=idx,
                         columns=["o_x", "o_y", "o_z", "a_x", "a_y", "a_z"])
    return frame, o, a, amb


def test_ground_product_removes_the_tone_and_adds_no_noise(rng):
    frame, o, a, amb = _tone_pair(rng)
    model = PiCoG(PLAN).fit(frame)
    assert_allclose(model.M_["a"], -0.5 * np.outer(U, U), atol=0.01)   # Eq. 19, a = 3
    onboard = model.transform(frame)[["x", "y", "z"]].to_numpy()
    on_chk = band_check(o, onboard, 1 / 128)
    # the constant matrices inject the reference's noise: y and z worse than raw
    assert {w["component"] for w in on_chk.worse_than_raw} == {"y", "z"}
    d = model.delivery_
    assert d.kind in ("ground", "band_limited") and not d.collapses_to_on_board
    chk = band_check(o, d.product, 1 / 128)
    assert chk.worse_than_raw == []
    assert np.all(chk.reduction >= 1 / 1.1)
    tone = band_check(o, d.product, 1 / 128, bands_hz=[(34.0, 36.0)]).reduction[0]
    assert np.all(tone[1:] > 100)                               # removed where it was
    # away from the tone the product is the raw target's 0.01 nT, not the 0.1 nT injected
    away = [(1.0, 30.0)]
    # 0.027, 0.015
    assert np.all(band_check(o, onboard, 1 / 128, bands_hz=away).reduction[0, 1:] < 0.04)
    assert np.all(band_check(o, d.product, 1 / 128, bands_hz=away).reduction[0] > 0.9)
    doc = model.to_params()
    assert doc["delivered"] == d.kind and doc["ground"]["worse_than_raw"] == []
    assert doc["on_board"]["M"] == doc["M"] and doc["worse_than_raw"]   # on-board's
    # the warnings say which product is worse than raw: the constant matrices', not the
    # delivered one (it read "the cleaned o is worse than raw" beside a product that
    # passes its check)
    assert model.warnings_[0].startswith(f"delivered product: {d.kind} (")
    assert model.warnings_[0].endswith("its own band check passes in every band/component")
    assert any(w.startswith("the constant matrices' product of o is worse than raw")
               for w in model.warnings_), model.warnings_
    assert not any(w.startswith("the cleaned o is worse") for w in model.warnings_)


def test_apply_enforces_the_rule_and_says_why(rng, tmp_path, capsys):
    frame, o, _, _ = _tone_pair(rng, n=16384)
    src = tmp_path / "in.csv"
    out = frame.copy()
    out.index = out.index.strftime("%Y-%m-%dT%H:%M:%S.%f")
    out.index.name = "time"
    out.to_csv(src)
    plan = tmp_path / "plan.toml"
    plan.write_text('target = "o"\n[[stage]]\nreference = "a"\nsensors = ["o"]\n'
                    'orders = [ { direction = "coherent" } ]\n')
    params, clean = tmp_path / "p.json", tmp_path / "c.csv"
    assert main(["picog", "fit", str(src), "--plan", str(plan), "-o", str(params)]) == 0
    assert main(["picog", "apply", str(src), "--params", str(params), "-o", str(clean)]) == 0
    err = capsys.readouterr().err
    side = json.loads((tmp_path / "c.json").read_text())
    assert side["delivered"] in ("ground", "band_limited") and side["reason"]
    assert f"delivered {side['delivered']}" in err
    got = pd.read_csv(clean)
    assert list(got.columns) == ["time", "x", "y", "z", "flag"]
    assert band_check(o, got[["x", "y", "z"]].to_numpy(), 1 / 128).worse_than_raw == []


def test_deliver_falls_back_to_raw_and_tolerates_gaps(rng):
    n = 8192
    raw = rng.normal(0, 0.01, (n, 3))
    worse = raw + rng.normal(0, 1.0, (n, 3))        # a correction that only adds noise
    raw[1000:1200] = np.nan                           # samples QC flagged: NaN
    d = deliver(raw, worse, 0.1)
    # left out everywhere, below the check's lowest band too (the weight that minimises
    # the power of 0.01 nT raw plus w times 1 nT of noise is about 0.01)
    assert d.kind in ("ground", "band_limited", "raw")
    assert np.max(d.weights) < 0.05
    assert np.isnan(d.product[1000:1200]).all() and np.isfinite(d.product[:1000]).all()
    assert band_check(raw, d.product, 0.1).worse_than_raw == []


def _glitch_pair(rng, n=20000):
    """Target ``o`` and reference ``a`` with a slow disturber along U seen 3x at ``a``;
    truth ``A = 0.5 U U^T`` (as above)."""
    s = 5.0 * np.convolve(rng.normal(size=n), np.ones(20) / np.sqrt(20), mode="same")
    amb = np.array([100.0, -20.0, 40.0]) + rng.normal(0, 0.5, (n, 3)).cumsum(0) * 0.01
    o = amb + s[:, None] * U + 0.05 * rng.normal(size=(n, 3))
    a = amb + 3 * s[:, None] * U + 0.05 * rng.normal(size=(n, 3))
    return o, a


def _frame(o, a):
    idx = pd.date_range("2020-01-01", periods=len(o), freq="1s", tz="UTC")
    return pd.DataFrame(np.hstack([o, a]), index=idx,
                        columns=["o_x", "o_y", "o_z", "a_x", "a_y", "a_z"])


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_glitches_under_one_percent_do_not_turn_the_fit(seed):
    rng = np.random.default_rng(seed)
    o, a = _glitch_pair(rng)
    n = len(o)
    truth = 0.5 * np.outer(U, U)
    # 0.5 % spikes of 30-300 nT in one component of the reference, 0.3 % of the target
    # stuck in runs of 20 samples, 1 % NaN (samples QC flagged), all passing to the fit
    spikes = rng.choice(n, n // 200, replace=False)
    a[spikes, rng.integers(0, 3, spikes.size)] += rng.choice([-1, 1], spikes.size) * \
        rng.uniform(30, 300, spikes.size)
    for start in rng.choice(n - 20, 3, replace=False):
        o[start:start + 20] = o[start]
    gaps = rng.choice(n, n // 100, replace=False)
    o[gaps] = np.nan
    robust = PiCoG(PLAN).fit(_frame(o, a))
    plain = PiCoG(PLAN, robust=False).fit(_frame(o, a))
    A = lambda m: -m.M_["a"]                                      # noqa: E731
    # clean: within 2e-4 of the truth; the few glitches left (a spike next to a
    # disturbance peak of the other sensor is kept) cost up to 2.5 % of alpha
    assert np.max(np.abs(A(robust) - truth)) < 0.0125 * 2, A(robust)
    assert np.max(np.abs(A(plain) - truth)) > 0.1                 # what the glitches do
    flagged = robust.outliers_["flagged"]
    assert flagged["a"] >= 0.9 * spikes.size and flagged["o"] >= 0.9 * 60
    assert robust.outliers_["rows_left_out"] < 0.02 * n


def test_clean_pair_loses_no_sample():
    o, a = _glitch_pair(np.random.default_rng(4))
    m = PiCoG(PLAN).fit(_frame(o, a))
    assert m.outliers_["rows_left_out"] == 0


def _red(rng, n, tau_s=300.0, sigma=0.3, white=0.1):
    """Fluxgate-like noise: an AR(1) process of correlation time ``tau_s`` (1 s samples)
    plus white noise, nT."""
    from scipy.signal import lfilter

    a = np.exp(-1.0 / tau_s)
    e = rng.normal(0, sigma * np.sqrt(1 - a * a), (n, 3))
    return lfilter([1.0], [1.0, -a], e, axis=0) + rng.normal(0, white, (n, 3))


def _slow_case(seed, kind, size_nT, n=7200):
    """Two hours at 1 s below the check's lowest band (4.4 mHz): the target sees a
    geostationary-like ambient field (drifts of 5-20 nT, a 0.5 nT 15-min wave), its own
    red noise and a disturber ``d``; the correction removes ``d`` and adds half the
    partner's red noise. Returns the delivered product's error rms over raw's (both
    against the ambient truth, means removed)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=float)
    amb = np.column_stack([20 * np.sin(2 * np.pi * 3 * t / 86400 + 1),
                           5 * np.cos(2 * np.pi * 2 * t / 86400), 10 * t / n])
    amb += 0.5 * np.sin(2 * np.pi * t / 900)[:, None]
    own, partner = _red(rng, n), _red(rng, n)
    d = np.zeros((n, 3))
    if kind == "cycle":                  # a heater cycling every 20 min, along x
        d[:, 0] = size_nT * np.sin(2 * np.pi * t / 1200)
    elif kind == "step":                 # a unit switched on after 50 min, along y
        d[t > 3000, 1] = size_nT
    raw = amb + d + own
    product = deliver(raw, raw - d + 0.5 * partner, 1.0).product
    err, err_raw = product - amb, raw - amb
    return float(np.std(err - err.mean(0)) / np.std(err_raw - err_raw.mean(0)))


def test_nothing_to_remove_below_the_lowest_band_adds_no_red_noise():
    """A quiet record (nothing to remove, the correction is half the partner's red
    noise): below the check's lowest band the full correction used to be kept, which
    put the partner's red noise into the product (error 1.039x raw's on average over
    these 30 draws, up to 1.17x; 1.005 and 1.08x with the bands judged; measured 1.003
    and 1.055x now). The record's own Fourier coefficients judge those bands now, and
    one it cannot judge takes the weight of the band above, which the lowest checked
    band passes down only where the correction helps over the checked bands."""
    ratios = np.array([_slow_case(seed, "quiet", 0.0) for seed in range(30)])
    assert ratios.mean() <= 1.01 and ratios.max() <= 1.1, ratios


@pytest.mark.parametrize("kind, size_nT, bound", [
    ("cycle", 5.0, 0.45), ("cycle", 20.0, 0.05), ("step", 2.0, 0.56), ("step", 5.0, 0.25)])
def test_slow_disturbers_below_the_lowest_band_are_still_removed(kind, size_nT, bound):
    """A 20-min heater cycle or a step in a 2 h record lives below the check's lowest
    band; where the record shows the correction lowering the power there beyond the
    ambient field's scatter it is kept. Bounds: the mean error rms over raw's of 20
    draws with the full correction kept below the lowest band (0.408, 0.039, 0.501,
    0.220) plus 10 %; measured 0.362, 0.038, 0.540, 0.215 (the 2 nT step is at the edge
    of detection: the lowest checked band's partial weight, no longer passed down where
    the correction does not help over the checked bands, removed some of it)."""
    ratios = np.array([_slow_case(seed, kind, size_nT) for seed in range(20)])
    assert ratios.mean() <= bound, ratios


SAMPLES = __import__("pathlib").Path(__file__).resolve().parents[1] / "data_samples"


def _quiet_record(truth: pd.DataFrame, seed: int, n: int = 7200):
    """Two hours of the shipped geostationary sample's ambient field (its fgmo truth) at
    a seeded start, seen by fgmo and fgmi with independent red plus white noise each
    (:func:`_red`) and nothing else: nothing to remove. Returns the frame and the
    ambient truth."""
    rng = np.random.default_rng(seed)
    start = int(rng.integers(0, len(truth) - n))
    amb = truth[["fgmo_x", "fgmo_y", "fgmo_z"]].to_numpy()[start:start + n]
    o, i = amb + _red(rng, n), amb + _red(rng, n)
    idx = pd.to_datetime(truth["time"].iloc[start:start + n].to_numpy(), utc=True)
    cols = [f"{s}_{c}" for s in ("fgmo", "fgmi") for c in "xyz"]
    return pd.DataFrame(np.hstack([o, i]), index=idx, columns=cols), amb


def test_quiet_records_are_not_made_worse_below_the_check():
    """Quiet 2 h records (the sample's ambient field, independent red and white noise in
    both fluxgates) cleaned with a fixed pair plan: the pair's weight is fitted on noise,
    so the correction can lower the error (averaging the two sensors) or raise it.
    Below the check's lowest band the ambient field dominates raw, and the lowest
    checked band's full weight, kept there because the correction raised raw's power by
    less than RISE_TOLERANCE, was passed down to every band below: over these 35 draws
    12 came out more than 2 % worse than raw against the ambient truth (up to 1.70x),
    mean 1.010. It is passed down only where the correction lowers raw's power over the
    checked bands beyond chance now: measured 5 draws above 1.02, mean 0.974 (the rest
    is mostly the 2-sigma judgement of single low bands)."""
    from magcal.ac.plan import plan_from_dict

    plan, _ = plan_from_dict({"target": "fgmo", "stage": [
        {"pair": ["fgmo", "fgmi"], "orders": [{"window_s": 300}, {"window_s": 1800}]}]})
    truth = pd.read_csv(SAMPLES / "geostationary_3days_truth.csv.gz")
    ratios = []
    for seed in range(100, 135):
        frame, amb = _quiet_record(truth, seed)
        product = PiCoG(plan).fit(frame).delivery_.product
        err, err_raw = product - amb, frame.iloc[:, :3].to_numpy() - amb
        ratios.append(np.std(err - err.mean(0)) / np.std(err_raw - err_raw.mean(0)))
    ratios = np.array(ratios)
    assert np.sum(ratios > 1.02) <= 7 and ratios.mean() <= 0.99, np.round(ratios, 3)


# ------------------------------------------------------------------- real records
@pytest.fixture(scope="module")
def bench():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_picog_bands.py"
    spec = importlib.util.spec_from_file_location("bench_picog_bands", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.realdata
def test_venus_express_tones_down_and_no_band_worse(bench, real_data, tmp_path):
    frame = bench._vex_frame(real_data("multi-sensor", "VEX128.txt"))
    raw, clean, doc, dt = bench.run_cli(frame, "bos", tmp_path, "vex")
    chk = band_check(raw, clean, dt)
    assert chk.worse_than_raw == [] and np.all(chk.reduction >= 1 / 1.1)
    tone = band_check(raw, clean, dt, bands_hz=[(33.0, 37.0)]).reduction[0]
    assert np.all(tone >= 9.0), tone                      # measured 9.6, 35, 28
    assert doc["worse_than_raw"]        # the constant matrices alone were worse (1.49-2.3x)


@pytest.mark.realdata
def test_mst_no_band_worse_and_closer_to_the_ambient(bench, real_data, tmp_path):
    frame, amb = bench._mst_frame(real_data("multi-sensor", "mstac2e2esupp1.csv"))
    raw, clean, doc, dt = bench.run_cli(frame, "bout", tmp_path, "mst")
    assert band_check(raw, clean, dt).worse_than_raw == []
    ac = np.std(clean - amb, axis=0)
    assert ac.mean() <= 0.105 and np.all(ac < np.std(raw - amb, axis=0))


@pytest.mark.realdata
@pytest.mark.parametrize("folder", ["l2_hires_5min", "l2_hires_gap"])
def test_goes16_no_band_worse(bench, real_data, tmp_path, folder):
    frame = bench._goes_frame(real_data("goes16", folder))
    raw, clean, doc, dt = bench.run_cli(frame, "ob", tmp_path, folder)
    assert band_check(raw, clean, dt).worse_than_raw == []
    assert doc["delivered"] in ("on_board", "ground", "band_limited", "raw")


@pytest.mark.parametrize("seed", [1, 6])
def test_auto_day_removes_1000x_through_the_cli(bench, tmp_path, seed):
    """``picog fit --auto`` + ``apply`` on a GK-2A-like day at 4 s (three sensors, four
    disturbers, no boom shadow): at least 1000x of the disturbance power against the
    simulator's truth (issue 22 part 3). Measured 1795x and 1889x here (seeds 1-6:
    868-1889x; 642x and 298x before the partner was kept out of the
    reference choice and the pair orders were fitted jointly)."""
    from magcal.simulate.geostationary import GeostationaryConfig, simulate_geostationary
    from magcal.simulate.gk2a import gk2a_disturbers, gk2a_sensors

    sens = tuple(s for s in gk2a_sensors() if s.name in ("fgmo", "fgmi", "amr1"))
    dist = tuple(d for d in gk2a_disturbers()
                 if d.name in ("midnight", "spikes", "hf_noise", "steps"))
    cfg = GeostationaryConfig.gk2a_like(sensors=sens, disturbers=dist, cadence_s=4.0,
                                        shadow=None)
    res = simulate_geostationary(cfg, rng=np.random.default_rng(seed))
    raw, out, doc, dt = bench.run_cli(res.measurements, "fgmo", tmp_path, f"day{seed}")
    clean = res.truth.clean("fgmo")
    assert_allclose(raw, res.sensor("fgmo"), atol=1e-6)
    ratio = np.sum(np.var(raw - clean, axis=0)) / np.sum(np.var(out - clean, axis=0))
    assert ratio >= 1000, (ratio, doc["auto"]["choices"])
    assert any(s.get("joint") for s in doc["plan"]["stages"]), doc["plan"]


@pytest.mark.slow
def test_simulated_day_delivered_removes_what_the_matrices_remove():
    """A GK-2A-like day, three sensors, four disturbers (truth from the simulator) with
    the boom shadow: the delivered product keeps the on-board removal (measured 440x
    on-board, 1989x delivered; 342x at a887a98). The inboard sensor's shadow offsets
    (not part of fgmo's truth) enter the constant matrices through the pair's weight;
    the delivered product keeps their smooth part out (tests/test_ac_slow.py asks it
    for 1000x)."""
    from magcal.ac.chain import apply_weights
    from magcal.ac.metrics import disturbance_power_ratio
    from magcal.simulate.geostationary import GeostationaryConfig, simulate_geostationary
    from magcal.simulate.gk2a import gk2a_disturbers, gk2a_sensors

    sens = tuple(s for s in gk2a_sensors() if s.name in ("fgmo", "fgmi", "amr1"))
    dist = tuple(d for d in gk2a_disturbers()
                 if d.name in ("midnight", "spikes", "hf_noise", "steps"))
    res = simulate_geostationary(GeostationaryConfig.gk2a_like(sensors=sens, disturbers=dist),
                                 rng=np.random.default_rng(1))
    m = PiCoG(target="fgmo", auto=True).fit(res.measurements)
    data = {s.name: res.sensor(s.name) for s in sens}
    clean = res.truth.clean("fgmo")
    onboard = disturbance_power_ratio(data["fgmo"] - clean,
                                      apply_weights(data, m.M_) + m.G_ - clean)
    delivered = disturbance_power_ratio(data["fgmo"] - clean, m.delivery_.product - clean)
    assert onboard > 250 and delivered > 0.9 * onboard, (onboard, delivered)
    assert m.outliers_["rows_left_out"] == 0                  # no disturber taken for a glitch
    assert band_check(data["fgmo"], m.delivery_.product, 1.0).worse_than_raw == []
