"""The main job end to end: ``magcal demo`` is ``magcal run`` on the shipped chain
configurations, and every product is scored against the simulator's truth.

The geostationary chain simulates a quarter (91 days) of raw two-sensor 10 s daily files
with a slow drift (0.04/-0.03/0.02 nT/day) and a step (3/-2/1.5 nT on 2019-12-12) in
the offset, two linearly polarised spacecraft disturbers, the local-time field T89
lacks and a storm-time field that follows Dst. The spinning chain runs the Galileo-like
sample (truth in data_samples/spinning_galileo_truth.json).
"""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from magcal.cli import main
from magcal.provenance import file_sha256

# one test process for the whole module (pyproject runs pytest with --dist loadgroup):
# its module fixture (the whole demo, 75 s) is then computed once instead of once per
# process
pytestmark = pytest.mark.xdist_group("demo")

DATA = Path(__file__).resolve().parents[1] / "data_samples"


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    if not (DATA / "chain" / "CHAIN.toml").exists():
        pytest.skip("data_samples/chain missing")
    out = tmp_path_factory.mktemp("demo")
    status = main(["demo", "--data", str(DATA), "-o", str(out), "--quiet"])
    manifest = json.loads((out / "MANIFEST.json").read_text())
    return status, out, manifest


def _json(path):
    return json.loads(Path(path).read_text())


@pytest.mark.slow
def test_every_stage_runs_and_the_manifest_traces_every_product(demo):
    status, out, manifest = demo
    assert status == 0 and manifest["failed"] == []
    stages = {p["stage"] for p in manifest["products"]}
    assert {"read", "frames", "ac", "model", "offsets", "corrected", "alignment", "discover",
            "truth", "report"} <= stages
    raw = sorted((out / "raw").glob("day_*.csv"))
    assert len(raw) == 91  # a quarter of daily files, simulated from the seed
    assert {i["sha256"] for i in manifest["inputs"]} == {file_sha256(p) for p in raw}
    for entry in manifest["products"]:
        assert file_sha256(out / entry["path"]) == entry["sha256"]
    for name in ("offsets/OFFSETS.csv", "alignment/ALIGN.json", "report/REPORT.html",
                 "ac/PARAMS.json", "discover/REPORT.json"):
        assert (out / name).is_file()
    spin = _json(out / "spinning" / "MANIFEST.json")
    assert spin["failed"] == []


@pytest.mark.slow
def test_corrected_files_cover_every_input_time(demo):
    out = demo[1]
    n_raw = sum(len(pd.read_csv(p, usecols=["time"])) for p in (out / "raw").glob("day_*.csv"))
    corrected = sorted((out / "corrected").glob("CORRECTED_*.csv"))
    assert len(corrected) == 91
    frames = [pd.read_csv(p) for p in corrected]
    assert sum(len(f) for f in frames) == n_raw
    assert list(frames[0].columns[:4]) == ["time", "Hp", "He", "Hn"]


@pytest.mark.slow
def test_offset_product_follows_the_injected_drift_and_step(demo):
    truth = _json(demo[1] / "truth" / "TRUTH.json")["offsets"]
    # Away from the step, each 28-day median of ~9000 quiet 1-min samples with the model
    # that made the data leaves only the local-time field's imbalance: 0.3 nT rms.
    assert truth["rms_away_from_steps_nT"] < 0.3
    assert truth["max_abs_away_from_steps_nT"] < 0.6
    # Near the step the windows straddle it: the error cannot exceed the step itself.
    assert truth["max_abs_nT"] < 3.0
    table = pd.read_csv(demo[1] / "offsets" / "OFFSETS.csv", parse_dates=["start", "end"])
    before = table[table["end"] <= "2019-12-12"]
    after = table[table["start"] >= "2019-12-12"]
    assert len(before) and len(after)
    days = (pd.to_datetime(after["center"].iloc[0]) - pd.to_datetime(before["center"].iloc[-1])
            ).total_seconds() / 86400
    jump = after[["Hp", "He", "Hn"]].iloc[0] - before[["Hp", "He", "Hn"]].iloc[-1]
    expected = np.array([3.0, -2.0, 1.5]) + np.array([0.04, -0.03, 0.02]) * days
    np.testing.assert_allclose(jump.to_numpy(), expected, atol=0.4)


@pytest.mark.slow
def test_the_injected_offset_step_is_named_and_the_samples_across_it_flagged(demo):
    """The offsets stage names the injected step, and nothing else, at its true time
    (within its 95 % interval), with sizes within 2.5 standard errors of 3/-2/1.5 nT;
    the corrected files carry quality bit 128 exactly between the centres of the last
    window before it and the first after it."""
    out = demo[1]
    truth = pd.read_csv(out / "raw" / "truth.csv", parse_dates=["time"])
    jump = truth["offset_Hp"].diff().abs().to_numpy()
    t_step = truth["time"].iloc[int(np.nanargmax(jump))]
    changes = _json(out / "offsets" / "OFFSETS.csv.provenance.json")["level_changes"]
    assert len(changes) == 1, changes
    lo, hi = (pd.Timestamp(v) for v in changes[0]["time_ci95"])
    assert lo <= t_step <= hi
    size = np.array([changes[0]["size_nT"][c] for c in ("Hp", "He", "Hn")])
    se = np.array([changes[0]["se_nT"][c] for c in ("Hp", "He", "Hn")])
    assert np.all(np.abs(size - [3.0, -2.0, 1.5]) <= 2.5 * se), (size, se)
    at = pd.Timestamp(changes[0]["time"])
    table = pd.read_csv(out / "offsets" / "OFFSETS.csv", parse_dates=["center", "start", "end"])
    before = table["center"][table["end"] <= at].iloc[-1]
    after = table["center"][table["start"] >= at].iloc[0]
    days = pd.date_range(before.floor("D") - pd.Timedelta(days=2), after + pd.Timedelta(days=2))
    for day in days:
        f = pd.read_csv(out / "corrected" / f"CORRECTED_{day:%Y%m%d}.csv",
                        parse_dates=["time"])
        t = f["time"].dt.tz_localize(None)
        inside = ((t > before) & (t < after)).to_numpy()
        np.testing.assert_array_equal((f["quality"].to_numpy() & 128) > 0, inside)
    # and the uncertainty report lists it with its interval
    html = (out / "report" / "REPORT.html").read_text()
    assert "Sudden level changes of the offset" in html
    assert f"{lo:%Y-%m-%d} .. {hi:%Y-%m-%d}" in html


@pytest.mark.slow
def test_picog_removes_the_disturbers(demo):
    truth = _json(demo[1] / "truth" / "TRUTH.json")["ac"]
    assert truth["power_reduction"] > 100  # two linear disturbers, exact gradiometer case
    params = _json(demo[1] / "ac" / "PARAMS.json")
    total = sum(np.asarray(m) for m in params["M"].values())
    np.testing.assert_allclose(total, np.eye(3), atol=1e-12)  # PiCoG Eq. 33
    assert _json(demo[1] / "ac" / "AC.json")["delivered"] == "cleaned"


@pytest.mark.slow
def test_alignment_covers_the_true_zero_rotation(demo):
    align = _json(demo[1] / "alignment" / "ALIGN.json")
    for c in ("Hp", "He", "Hn"):
        lo, hi = align["ci95_deg"][c]
        assert lo <= 0.0 <= hi
        assert abs(align["angles_deg"][c]) < 3.0


@pytest.mark.slow
def test_discovery_names_what_was_injected_and_nothing_else(demo):
    # injected: the offset with its drift and step, the local-time field T89 lacks and
    # the storm-time field that follows Dst (given as a covariate); not injected: any
    # rotation, scale, temperature or periodic term
    report = _json(demo[1] / "discover" / "REPORT.json")
    names = [e["name"] for e in report["effects"]]
    assert names[0] == "offset"
    assert {"diurnal", "activity", "step"} <= set(names), names
    assert set(names) <= {"offset", "diurnal", "activity", "step", "drift"}, names
    step = next(e for e in report["effects"] if e["name"] == "step")["parameters"]
    assert abs(pd.Timestamp(step["time"]) - pd.Timestamp("2019-12-12T00:00:00Z")) \
        < pd.Timedelta(hours=6), step
    assert report["gap_final"]["rms_nT"] < 0.05 * report["gap_initial"]["rms_nT"]


@pytest.mark.slow
def test_spinning_chain_recovers_the_true_calibration(demo):
    out = demo[1] / "spinning"
    truth = _json(out / "truth" / "TRUTH.json")
    flip = _json(out / "spin" / "FLIP.json")
    cal = _json(out / "spin" / "CAL.json")
    assert truth["max_c3x_error_deg"] < 0.01 and truth["max_o12_error_nT"] < 0.05
    assert abs(truth["o3_error_nT"]) < 4 * flip["O3_std"]
    after = max(max(v) for v in cal["spin_tone_after_nT"].values())
    before = max(max(v) for v in cal["spin_tone_before_nT"].values())
    assert after < 0.01 < before
    despun = pd.read_csv(out / "despun" / "DESPUN.csv")
    assert list(despun.columns) == ["time", "BX", "BY", "BZ"] and len(despun) == 81000
