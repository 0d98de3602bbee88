"""Quality screen of spinning records (fills, saturation, spikes) and the never-worse
guard of ``spincal``, against the simulator's injected offsets O = (0.8, -1.3, 0.45).

Before the screen, on the Galileo-like sample: a 10-minute flat b1 gave O1 = -164 nT,
0.5 % spikes O = (-2.2, -4.1) nT, 99999 fills in b2 O2 = 1322 nT, and the flipper's
O3 on the fill file 0.89 nT; all exited 0 without a word.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from magcal.cli import main
from magcal.simulate.spinning import SpinningConfig, simulate_spinning
from magcal.spin.inputs import load_spin_data
from magcal.spin.product import flipper, spincal, tone_worse
from magcal.spin.screen import screen_spin

TRUE_O = np.array([0.8, -1.3, 0.45])


def _sim(seed):
    cfg = SpinningConfig.galileo_like(duration_s=5400.0, flip_intervals_s=((3600.0, 5400.0),))
    return simulate_spinning(cfg, rng=np.random.default_rng(seed))


def _write(frame, path):
    out = frame.copy()
    out.index = out.index.tz_localize(None)
    out.to_csv(path, date_format="%Y-%m-%dT%H:%M:%S.%f")
    return path


def _messy(sim, kind, seed):
    d = sim.data.copy()
    n = len(d)
    rng = np.random.default_rng(1000 + seed)
    if kind == "spikes":        # 0.5 % of rows, 30-300 nT in every component
        rows = rng.choice(n, n // 200, replace=False)
        for c in ("b1", "b2", "b3"):
            d.iloc[rows, d.columns.get_loc(c)] += (rng.uniform(30, 300, rows.size)
                                                   * rng.choice([-1, 1], rows.size))
    elif kind == "saturation":  # b1 flat above its range for 10 minutes
        s0 = n // 4
        d.iloc[s0:s0 + 2571, d.columns.get_loc("b1")] = d["b1"].max() + 50.0
    elif kind == "fill":        # 99999 in b2
        rows = rng.choice(n, n // 200, replace=False)
        d.iloc[rows, d.columns.get_loc("b2")] = 99999.0
    return d


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("kind", ["spikes", "saturation", "fill"])
def test_messy_spin_records_recover_the_injected_offsets(tmp_path, kind, seed):
    sim = _sim(seed)
    path = _write(_messy(sim, kind, seed), tmp_path / "spin.csv")
    data = load_spin_data(path)
    assert data.screened["samples"] > 0
    cal = spincal(data).calibration
    for k in (0, 1):            # O1, O2 (O3 is fixed in the ripple fit)
        assert abs(cal.offsets_nT[k] - TRUE_O[k]) < 0.15, (kind, cal.offsets_nT)
        assert abs(cal.offsets_nT[k] - TRUE_O[k]) < 4 * cal.std[f"O{k + 1}"]
    flip = flipper(data, coupling=sim.truth.coupling, offsets=sim.truth.offsets_nT).result
    assert abs(flip.O3 - TRUE_O[2]) < 0.1 and abs(flip.O3 - TRUE_O[2]) < 4 * flip.O3_std
    doc = spincal(data).to_json()
    assert doc["screened"]["samples"] == data.screened["samples"]
    assert doc["delivered"] == "fitted"


@pytest.mark.parametrize("seed", [0, 1])
def test_screen_flags_nothing_on_clean_records(tmp_path, seed):
    sim = _sim(seed)
    bad, rec = screen_spin(sim.truth.t_s, sim.data[["b1", "b2", "b3"]].to_numpy())
    assert rec["samples"] == 0 and not bad.any()
    path = _write(sim.data, tmp_path / "clean.csv")
    on, off = load_spin_data(path), load_spin_data(path, screen=False)
    assert on.screened["samples"] == 0 and off.screened is None
    a, b = spincal(on).calibration, spincal(off).calibration
    assert np.array_equal(a.coupling, b.coupling) and np.array_equal(a.offsets_nT, b.offsets_nT)


def test_screen_counts_each_test():
    p = np.arange(8000) * 2 * np.pi / 86
    b = np.column_stack([30 * np.cos(p), -30 * np.sin(p), np.full_like(p, 20.0)])
    b += np.random.default_rng(0).normal(0, 0.05, b.shape)
    b[[500, 501]] += [25.0, -10.0, 5.0]           # a two-sample spike
    b[3000, 2] = -99999.0                         # a fill
    b[5000:5400, 1] = b[:, 1].max() + 40.0        # saturated
    bad, rec = screen_spin(p * 0.233, b)
    assert (rec["spike"], rec["fill"], rec["saturated_or_stuck"]) == (2, 1, 400)
    assert rec["samples"] == int(bad.sum()) == 403


def test_never_worse_delivers_the_prior_with_the_reason(tmp_path):
    import dataclasses

    from magcal.spin.product import _deliver

    sim = _sim(0)
    cal = spincal(load_spin_data(_write(sim.data, tmp_path / "c.csv"))).calibration
    # a fit whose 2x tone in BX rose from 0.056 to 0.336 nT (the sweep's spiky record)
    after = dict(cal.spin_tone_after_nT, BX=[0.2, cal.spin_tone_before_nT["BX"][1] + 0.3])
    bad = dataclasses.replace(cal, spin_tone_after_nT=after)
    delivered, record = _deliver(bad, np.eye(3), np.zeros(3))
    assert record["delivered"] == "prior" and "BX 2x" in record["reason"]
    assert np.array_equal(delivered.coupling, np.eye(3))
    assert np.array_equal(delivered.offsets_nT, np.zeros(3))
    assert delivered.determined == () and delivered.spin_tone_after_nT == cal.spin_tone_before_nT
    assert record["fitted"]["offsets"] == cal.offsets_nT.tolist()
    # the clean fit is delivered as fitted
    assert _deliver(cal, np.eye(3), np.zeros(3))[1]["delivered"] == "fitted"
    # the guard itself: any component's tone up by more than its noise floor
    assert tone_worse({"BX": [1.2, 0.056]}, {"BX": [0.2, 0.336]}, {"BX": [0.01, 0.01]}) == [
        ("BX", 2, 0.056, 0.336)]
    assert tone_worse({"BX": [1.2, 0.056]}, {"BX": [0.2, 0.05]}, {"BX": [0.01, 0.01]}) == []


def test_cli_reports_what_was_screened(tmp_path, capsys):
    sim = _sim(0)
    path = _write(_messy(sim, "spikes", 0), tmp_path / "spikes.csv")
    out = tmp_path / "CAL.json"
    assert main(["spincal", str(path), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "screened:" in err and "spike" in err
    doc = json.loads(out.read_text())
    assert doc["screened"]["spike"] > 0 and doc["delivered"] == "fitted"
    assert main(["flipper", str(path), "-o", str(tmp_path / "FLIP.json")]) == 0
    assert "screened:" in capsys.readouterr().err
    flip = json.loads((tmp_path / "FLIP.json").read_text())
    assert flip["screened"]["samples"] == doc["screened"]["samples"]


def test_chain_read_stage_reports_what_was_screened(tmp_path, capsys):
    """``magcal run`` on a spiky spinning file says how many rows its stages left out
    (READ.json ``screened``, the stage's line), as ``spincal`` does: the despun product
    has no row there, which was silent before."""
    sim = _sim(0)
    path = _write(_messy(sim, "spikes", 0), tmp_path / "spikes.csv")
    cfg = tmp_path / "SPIN.toml"
    cfg.write_text(f'[input]\nfiles = ["{path.as_posix()}"]\n[spin]\nspin_period_s = 20.0\n'
                   "flipper = true\n")
    assert main(["run", str(cfg), "-o", str(tmp_path / "out")]) == 0
    read = json.loads((tmp_path / "out" / "read" / "READ.json").read_text())
    direct = load_spin_data(path).screened
    assert read["screened"] == json.loads(json.dumps(direct))
    assert direct["spike"] >= 0.9 * (len(sim.data) // 200)      # the injected 0.5 %
    out = capsys.readouterr()
    assert f"screened: {direct['samples']} samples left out" in out.out + out.err
    despun = (tmp_path / "out" / "despun" / "DESPUN.csv").read_text().count("\n") - 1
    assert despun == len(sim.data) - direct["samples"]


def test_chain_spin_warning_is_spincals_guard_only(tmp_path):
    """A record with no ripple to remove (identity coupling, zero offsets, seed 3): the
    fit moves the largest spin tone within its noise floor (1.2e-3 nT before and after),
    so spincal's guard delivers the fit without a warning, and the chain must not add
    one of its own (it did, comparing the largest tones alone)."""
    cfg = SpinningConfig.galileo_like(duration_s=5400.0, coupling=tuple(map(tuple, np.eye(3))),
                                      offsets_nT=(0.0, 0.0, 0.0))
    sim = simulate_spinning(cfg, rng=np.random.default_rng(3))
    path = _write(sim.data, tmp_path / "quiet.csv")
    doc = spincal(load_spin_data(path)).to_json()
    before = max(max(v) for v in doc["spin_tone_before_nT"].values())
    after = max(max(v) for v in doc["spin_tone_after_nT"].values())
    assert doc["delivered"] == "fitted" and after > before   # the case the old rule caught
    assert not tone_worse(doc["spin_tone_before_nT"], doc["spin_tone_after_nT"],
                          doc["spin_tone_noise_nT"])
    conf = tmp_path / "SPIN.toml"
    conf.write_text(f'[input]\nfiles = ["{path.as_posix()}"]\n[spin]\nspin_period_s = 20.0\n'
                    "flipper = false\n")
    assert main(["run", str(conf), "-o", str(tmp_path / "out")]) == 0
    manifest = json.loads((tmp_path / "out" / "MANIFEST.json").read_text())
    assert not [w for w in manifest["warnings"] if "spin tone" in w], manifest["warnings"]
