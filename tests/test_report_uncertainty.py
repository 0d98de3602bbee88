"""``magcal report``: uncertainty report built from a small products folder."""

from __future__ import annotations

import base64
import json
import re

import numpy as np
import pandas as pd
import pytest

from magcal.cli import main
from magcal.io.csv import write_csv_frame
from magcal.io.jsonio import write_json
from magcal.provenance import make_provenance

# one test process for the whole module (pyproject runs pytest with --dist loadgroup):
# its module fixtures (chain runs for the report, 16 s) are then computed once instead
# of once per process
pytestmark = pytest.mark.xdist_group("report_uncertainty")


@pytest.fixture(scope="module")
def products(tmp_path_factory):
    """ac/ (two plans, raw input reachable), offsets/ (two estimators), alignment/
    (magcal align --mcmc on a 12-day synthetic pair), spin/CAL.json, discover/REPORT.json."""
    from magcal.alignment.synthetic import synthetic_pair

    root = tmp_path_factory.mktemp("products")
    rng = np.random.default_rng(5)
    # --- ac: 1 Hz, 3 h; raw = clean + a 30 s disturbance
    n = 3 * 3600
    idx = pd.date_range("2019-03-04", periods=n, freq="1s", tz="UTC", name="time")
    clean = rng.normal(0.0, 0.1, (n, 3)) + [10.0, 20.0, 30.0]
    dist = 2.0 * np.sin(2 * np.pi * np.arange(n) / 30.0)[:, None] * [1.0, 0.5, 0.2]
    (root / "ac").mkdir()
    raw_path = root / "raw.csv"
    write_csv_frame(raw_path, pd.DataFrame(clean + dist, index=idx,
                                           columns=["fgmo_x", "fgmo_y", "fgmo_z"]))
    for name, scale in (("paper", 0.0), ("regression", 0.05)):
        write_csv_frame(root / "ac" / f"CLEAN_{name}.csv.gz", pd.DataFrame(
            clean + scale * dist, index=idx, columns=["x", "y", "z"]))
        write_json(root / "ac" / f"PARAMS_{name}.json", {
            "target": "fgmo", "M": {"fgmo": np.eye(3).tolist(), "amr1": np.zeros((3, 3)).tolist()},
            "G": [0.0, 0.0, 0.0],
            "steps": [{"stage": 1, "order": 1, "i": "fgmo", "j": "amr1", "alpha": 0.98,
                       "direction_i": [1, 0, 0], "direction_ij": [1, 0, 0], "window_s": None}],
            "provenance": make_provenance("picog fit", {}, inputs=[raw_path])})
    # --- offsets
    (root / "offsets").mkdir()
    header = "center,start,end,Hp,He,Hn,Hp_std,He_std,Hn_std,n_used,fraction_used\n"
    rows = ["2019-11-15T00:00:00,2019-11-01T00:00:00,2019-11-29T00:00:00,"
            "15.5,38.3,-89.6,3.3,1.8,0.7,24660,0.61",
            "2019-11-22T00:00:00,2019-11-08T00:00:00,2019-12-06T00:00:00,"
            "15.7,38.2,-89.5,3.4,1.9,0.6,22680,0.68"]
    (root / "offsets" / "OFFSETS.csv").write_text(header + "\n".join(rows) + "\n")
    rows_b = [r.replace("15.5,38.3", "15.1,38.4") for r in rows]
    (root / "offsets" / "OFFSETS_lt_balanced.csv").write_text(header + "\n".join(rows_b) + "\n")
    # --- alignment through the CLI
    case = synthetic_pair(np.random.default_rng(21), n=3456, cadence_s=300.0,
                          rotvec_deg=(1.7, -0.5, -0.5), noise_tau_s=(1800.0,) * 3)
    tidx = pd.DatetimeIndex(case.times, name="time").tz_localize("UTC")
    write_csv_frame(root / "d.csv", pd.DataFrame(case.data, index=tidx, columns=["Hp", "He", "Hn"]))
    write_csv_frame(root / "r.csv", pd.DataFrame(case.ref, index=tidx, columns=["Hp", "He", "Hn"]))
    (root / "alignment").mkdir()
    assert main(["align", str(root / "d.csv"), "--reference", str(root / "r.csv"), "--mcmc",
                 "--seed", "1", "--lt-harmonics", "0", "-o",
                 str(root / "alignment" / "ALIGN.json")]) == 0
    (root / "d.csv").unlink()
    (root / "r.csv").unlink()
    # --- spin and discover
    (root / "spin").mkdir()
    write_json(root / "spin" / "CAL.json", {
        "coupling": np.eye(3).tolist(), "offsets": [0.1, 0.2, 0.3],
        "determined": ["O1", "O2"], "fixed": ["O3"],
        "std": {"O1": 0.00125, "O2": 0.0025}, "bias_correction": {"O1": 0.0, "O2": 0.000375},
        "leakage_correction": {"O1": -0.000625, "O2": 0.0},
        "spin_tone_before_nT": {"BX": [1.25, 0.5], "BY": [1.5, 0.25], "BZ": [0.75, 0.125]},
        "spin_tone_after_nT": {"BX": [0.0125, 0.005], "BY": [0.015, 0.0025],
                               "BZ": [0.0075, 0.00125]}})
    write_json(root / "spin" / "FLIP.json", {
        "O3": 0.4498, "O3_std": 0.000977, "O3_std_data": 0.000737,
        "O3_std_calibration": 0.000642, "O3_dof": 26})
    (root / "discover").mkdir()
    write_json(root / "discover" / "REPORT.json", {
        "gap_initial": {"rms_nT": 5.125}, "gap_final": {"rms_nT": 1.25},
        "stopped_because": "no candidate improves BIC",
        "effects": [{"name": "diurnal", "components": ["Hp"], "parameters": {},
                     "rms_before_nT": 5.125, "rms_after_nT": 1.25, "evidence": {}},
                    {"name": "step", "components": ["Hp", "He"],
                     "parameters": {"time": "2019-12-12T00:02:30+00:00",
                                    "time_ci95": ["2019-12-11T23:02:30+00:00",
                                                  "2019-12-12T01:02:30+00:00"]},
                     "rms_before_nT": 1.25, "rms_after_nT": 0.875, "evidence": {}},
                    {"name": "drift", "components": ["Hn"],
                     "parameters": {"break_time": "2019-12-14T09:00:00+00:00",
                                    "time_ci95": ["2019-12-13T20:00:00+00:00",
                                                  "2019-12-15T03:00:00+00:00"]},
                     "rms_before_nT": 0.875, "rms_after_nT": 0.75, "evidence": {}}]})
    return root


def _text(html):
    return re.sub(r"<[^>]+>", " ", html)


@pytest.mark.slow
def test_report_holds_the_product_numbers_and_embeds_every_figure(products, tmp_path):
    out, pdf = tmp_path / "REPORT.html", tmp_path / "REPORT.pdf"
    assert main(["report", str(products), "-o", str(out), "--pdf", str(pdf)]) == 0
    html = out.read_text()
    text = _text(html)
    align = json.loads((products / "alignment" / "ALIGN.json").read_text())
    for c in ("Hp", "He", "Hn"):  # alignment table, 3 decimals
        assert f"{align['angles_deg'][c]:.3f}" in text
        assert f"{align['std_deg'][c]:.3f}" in text
        assert f"{align['ci95_deg'][c][0]:.3f}" in text
    for v in ("15.50", "38.30", "-89.60", "24660", "0.40"):  # offsets table, |diff| 0.4
        assert v in text
    for v in ("5.125", "1.250", "diurnal", "1.2500", "0.0125"):  # discover and spin
        assert v in text
    # the spin parameters with their errors (O2: 0.2 +- 1.96 x 0.0025, bias 0.000375 nT,
    # O1's leakage correction -0.000625 nT) and the flipper's O3 with its two parts
    for v in ("0.0025", "0.0049", "0.000375", "-0.000625",
              "0.4498", "0.000977", "0.00191492", "0.000737",
              "0.000642", "26"):
        assert v in text, v
    # the step's time with its 95 % interval
    assert "2019-12-12 00:02 (95 %: after 2019-12-11 23:02, by 2019-12-12 01:02 UTC)" in text
    # and a drift's break with its own
    assert "2019-12-14 09:00 (95 %: after 2019-12-13 20:00, by 2019-12-15 03:00 UTC)" in text
    assert "Not available: no alignment/*conjunction*.json" in text
    # plan disagreement above 0.1 mHz: 0.05 x the 30 s wave of amplitude 2 -> rms 0.0707
    x_rms = 0.05 * 2.0 / np.sqrt(2.0)
    assert f"{x_rms:.3g}" in text
    # raw/clean power of the paper plan, summed over axes: (3 x 0.01 + (4 + 1 + 0.16) / 2)
    # / (3 x 0.01) = 87 (noise variance of 10800 samples known to ~1.4 %)
    m = re.search(r"paper\s+1\s+0\.0e\+00\s+0\.980 \.\. 0\.980\s+([0-9.]+)", text)
    assert m is not None
    np.testing.assert_allclose(float(m.group(1)), (0.03 + 5.16 / 2) / 0.03, rtol=0.05)
    # every figure is embedded as a decodable PNG; no external image references
    imgs = re.findall(r'<img [^>]*src="([^"]+)"', html)
    assert len(imgs) == 5  # PSD x2, offsets, corner, angles by window (12 days: 3 windows)
    for src in imgs:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    # PDF: one page per figure after the text pages
    n_pages = len(re.findall(rb"/Type\s*/Page\b", pdf.read_bytes()))
    # 4 text pages: about 130 lines at 62 a page (the spin parameters' and the
    # flipper's tables among them), plus long table rows wrapped in two
    assert n_pages == len(imgs) + 4


def test_missing_products_are_reported_not_errors(tmp_path):
    out = tmp_path / "r.html"
    (tmp_path / "empty").mkdir()
    assert main(["report", str(tmp_path / "empty"), "-o", str(out)]) == 0
    text = _text(out.read_text())
    assert text.count("Not available") == 6


def test_report_of_missing_folder_exits_2(tmp_path, capsys):
    assert main(["report", str(tmp_path / "nope"), "-o", str(tmp_path / "r.html")]) == 2
    assert "nope" in capsys.readouterr().err
    assert not (tmp_path / "r.html").exists()


def test_ac_quality_tables_hold_the_product_numbers(tmp_path):
    from magcal.report.uncertainty import ac_quality_items

    (tmp_path / "ac").mkdir()
    summ = lambda v, m: {"mean_abs_nT": v, "mean_module_nT": m}  # noqa: E731
    write_json(tmp_path / "ac" / "AC_QUALITY.json", {"plans": {"paper": {
        "pair": ["fgmi", "fgmo"], "target": "fgmo",
        "remnants": {
            "steps": {"n": 68, "times_s": [], "raw": summ([4.93, 1.39, 0.86], 5.66),
                      "clean": summ([0.37, 2.18, 0.96], 2.47)},
            "spikes": {"n": 388, "times_s": [], "raw": summ([2.37, 2.36, 3.68], 4.98),
                       "clean": summ([0.43, 1.46, 1.42], 2.11)},
            "hf": {"quiet_s": [0, 600], "disturbed_s": [600, 1200], "contrast": 1.25,
                   "raw_nT": [0.54, 0.16, 0.14], "clean_nT": [0.94, 0.45, 0.08]}},
        "stability": {"days": ["2019-03-04", "2019-03-05"], "bmaxdev_nT": 32.306,
                      "bmaxdev_ac_nT": 14.017, "steps": [
                          {"stage": 2, "order": 3, "i": "fgmo", "j": "fgmi", "kind": "picog",
                           "std_direction_i_deg": 4.75, "std_direction_ij_deg": 2.19,
                           "std_alpha": 1.7238, "mean_alpha": 0.2593, "n_fits": 2}]}}}})
    remn, stab, bmax = [it for it in ac_quality_items(tmp_path) if hasattr(it, "rows")]
    assert remn.rows[0] == ("paper", "steps", "68", "4.93", "1.39", "0.86", "5.66", "0.37",
                            "2.18", "0.96", "2.47")
    assert remn.rows[1][2] == "388" and remn.rows[1][-1] == "2.11"
    assert remn.rows[2][:4] == ("paper", "HF (contrast 1.2)", "-", "0.54")
    assert stab.rows[0] == ("paper", "2.3 fgmo-fgmi", "4.75", "2.19", "1.7", "0.259")
    assert bmax.rows[0] == ("paper", "2019-03-04, 2019-03-05", "32.306", "14.017")
    assert remn.source == stab.source == "ac/AC_QUALITY.json"


def test_alignment_not_determinable_is_reported_not_crashed(tmp_path):
    import json

    from magcal.report.uncertainty import build_uncertainty_report

    (tmp_path / "alignment").mkdir()
    doc = {"schema_version": 1, "magcal_version": "x", "method": "gls", "n_used": 4200,
           "determinable": False, "reason": "over 7 min the reference changes too little",
           "angles_deg": {c: None for c in ("Hp", "He", "Hn")},
           "std_deg": {c: None for c in ("Hp", "He", "Hn")},
           "ci95_deg": {c: [None, None] for c in ("Hp", "He", "Hn")}, "warnings": []}
    (tmp_path / "alignment" / "ALIGN.json").write_text(json.dumps(doc))
    report = build_uncertainty_report(tmp_path)
    text = " ".join(str(i.__dict__) for s in report.sections for i in s.items)
    assert "do not determine the rotation" in text and "changes too little" in text


def _tables(report):
    return {(s.title, i.caption): i for s in report.sections for i in s.items
            if hasattr(i, "rows")}


def _budget(report):
    table = next(i for i in report.sections[0].items if hasattr(i, "rows"))
    return {(r[0], r[1]): r for r in table.rows}


def test_budget_combines_the_products_per_band(products):
    """Below 0.1 mHz: offset estimator disagreement (0.4 nT in the fixture) and the
    alignment's largest angle std times the default 100 nT field, root sum of squares;
    the per-sample spread is shown but not added; no NaN cell anywhere."""
    from magcal.report.uncertainty import build_uncertainty_report

    report = build_uncertainty_report(products)
    rows = _budget(report)
    align = json.loads((products / "alignment" / "ALIGN.json").read_text())
    a_nT = np.deg2rad(max(align["std_deg"].values())) * 100.0
    assert float(rows[("below 0.1 mHz", "alignment")][2]) == pytest.approx(a_nT, abs=1e-3)
    assert float(rows[("below 0.1 mHz", "offset: estimator disagreement")][2]) == (
        pytest.approx(0.4, abs=1e-3))
    total = rows[("below 0.1 mHz", "TOTAL (root sum of squares)")]
    assert float(total[2]) == pytest.approx(np.hypot(0.4, a_nT), abs=2e-3)
    assert "lower bound" in total[4] and "standard error" in total[4]  # no Hp_se columns
    assert ("below 0.1 mHz", "offset: spread of quiet data - model (not added)") in rows
    x_rms = 0.05 * 2.0 / np.sqrt(2.0)  # the plans' disagreement: 0.05 x a 2 nT 30 s wave
    assert float(rows[("above 0.1 mHz", "AC cleaning floor")][2]) == pytest.approx(
        x_rms, abs=2e-3)
    assert float(rows[("direction", "TOTAL (root sum of squares)")][2]) == pytest.approx(
        max(align["std_deg"].values()), abs=1e-3)
    for table in _tables(report).values():
        for row in table.rows:
            assert not any(c.strip().lower() in ("nan", "-nan", "inf") for c in row), row


@pytest.fixture(scope="module")
def chain_run(tmp_path_factory):
    """An 8-day 1-min archive through ``magcal run`` with a PiCoG plan, alignment,
    discovery and the report (about 15 s)."""
    from test_chain_archive import PLAN, _archive

    tmp = tmp_path_factory.mktemp("chainreport")
    (tmp / "PLAN.toml").write_text(PLAN)
    cfg = _archive(tmp, n_days=8, plan="PLAN.toml", stages=True)
    cfg.write_text(cfg.read_text().replace("[report]\nenabled = false",
                                           "[report]\nenabled = true"))
    out = tmp / "out"
    assert main(["run", str(cfg), "-o", str(out), "--quiet", "--workers", "1"]) == 0
    return out


def test_chain_report_reads_the_chains_ac_products_and_offset_errors(chain_run):
    from magcal.offsets.table import read_offsets_csv
    from magcal.report.uncertainty import build_uncertainty_report

    text = _text((chain_run / "report" / "REPORT.html").read_text())
    assert "Not available: no ac/" not in text
    report = build_uncertainty_report(chain_run)
    ac = json.loads((chain_run / "ac" / "AC.json").read_text())
    params = json.loads((chain_run / "ac" / "PARAMS.json").read_text())
    tables = _tables(report)
    corr = dict(tables[("AC cleaning (PiCoG)", "PiCoG correction of the chain run.")].rows)
    assert corr["removed rms (nT)"] == f"{ac['removed_rms_nT']:.3f}"
    assert corr["correction steps"] == str(len(params["steps"]))
    bands = tables[("AC cleaning (PiCoG)", "Power ratio raw / cleaned per band of the fit "
                                           "data (PiCoG band check).")]
    assert len(bands.rows) == len(params["band_check"]["bands_hz"])
    # offsets: the standard errors of OFFSETS.csv, the spread apart
    table = read_offsets_csv(chain_run / "offsets" / "OFFSETS.csv")
    off = next(t for (s, c), t in tables.items() if s == "DC offsets" and "standard errors"
               in c)
    assert off.columns[4:13] == ("Hp se", "He se", "Hn se", "Hp 95 %", "He 95 %", "Hn 95 %",
                                 "Hp spread", "He spread", "Hn spread")
    ok = np.isfinite(table.offset_nT).all(axis=1)
    np.testing.assert_allclose([[float(x) for x in r[4:7]] for r in off.rows],
                               table.se_nT[ok], atol=0.006)
    # the 95 % half-width is Student's t on the stated degrees of freedom times the se
    from scipy.stats import t as student_t

    np.testing.assert_allclose([[float(x) for x in r[7:10]] for r in off.rows],
                               student_t.ppf(0.975, table.dof[ok]) * table.se_nT[ok],
                               atol=0.006)
    rows = _budget(report)
    assert float(rows[("below 0.1 mHz", "offset: standard error")][2]) == pytest.approx(
        float(np.nanmax(table.se_nT[ok])), abs=1e-3)
    for band in ("above 0.1 mHz", "below 0.1 mHz", "direction"):
        total = rows[(band, "TOTAL (root sum of squares)")]
        assert total[2] == "not computed" or float(total[2]) >= 0
        assert total[4]  # a verdict or the reason
    for table in tables.values():
        for row in table.rows:
            assert not any(c.strip().lower() in ("nan", "-nan", "inf") for c in row), row


def test_chain_discovery_states_each_amplitude_with_a_standard_error(chain_run):
    doc = json.loads((chain_run / "discover" / "REPORT.json").read_text())
    assert doc["effects"] and "tau_s" in doc["amplitude_noise"]
    for e in doc["effects"]:
        assert set(e["amplitude_se_nT"]) == set(e["amplitude_nT"]) <= set(e["components"])
        assert all(np.isfinite(v) and v >= 0 for v in e["amplitude_se_nT"].values())
    text = _text((chain_run / "report" / "REPORT.html").read_text())
    name, amp = doc["effects"][0]["name"], doc["effects"][0]["amplitude_nT"]
    c = next(iter(amp))
    assert f"{c} {amp[c]:.3f} +- " in text and name in text


@pytest.mark.parametrize("rel, text, message", [
    ("ac/PARAMS.json", '{"schema_version": 1, "M": ', "not valid JSON (line 1 column 28"),
    ("ac/PARAMS_paper.json", '{"schema_version": 1, "M": [[1, 0, 0]]}',
     "key 'M' is a list, expected a dict"),
    ("alignment/ALIGN.json", "[]", "expected a JSON object, found a list"),
    ("alignment/ALIGN.json", '{"method": "gls", "n_used": 5}', "missing key 'angles_deg'"),
    ("spin/CAL.json", '{"schema_version": 1}', "missing key 'spin_tone_before_nT'"),
    ("discover/REPORT.json", '{"schema_version": 1, "effects": []}',
     "missing key 'gap_initial'"),
])
def test_malformed_product_json_exits_2_naming_file_and_key(tmp_path, capsys, rel, text,
                                                            message):
    # sweep: these were internal errors (exit 1: JSONDecodeError, TypeError, KeyError)
    path = tmp_path / "products" / rel
    path.parent.mkdir(parents=True)
    path.write_text(text)
    out = tmp_path / "r.html"
    assert main(["report", str(tmp_path / "products"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{path}: {message}" in err and "internal error" not in err
    assert not out.exists()
