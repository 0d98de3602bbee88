"""``magcal qc`` checks every field column: a sensor missing a component, or with its
columns renamed with a unit suffix, is checked (per component) and named, never
skipped. Spikes injected at known rows must come back at exactly those rows."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from magcal.qc.files import FieldColumns, check_files

SPIKES = np.array([301, 777, 1500, 2222, 3001, 4444])


def _write(tmp_path, name, drop=(), rename=None):
    rng = np.random.default_rng(11)
    n = 5000
    t = pd.date_range("2019-03-04", periods=n, freq="1s", tz="UTC")
    cols = {}
    for s in ("fgmo", "fgmi"):
        for c in "xyz":
            cols[f"{s}_{c}"] = 100 + np.cumsum(rng.normal(0, 0.05, n))
    cols["fgmo_x"][SPIKES[:3]] += 40.0   # spikes on x ...
    cols["fgmo_z"][SPIKES[3:]] -= 40.0   # ... and on z of fgmo only
    frame = pd.DataFrame(cols, index=t).drop(columns=list(drop))
    if rename:
        frame = frame.rename(columns=rename)
    path = tmp_path / name
    frame.rename_axis("time").to_csv(path, date_format="%Y-%m-%dT%H:%M:%SZ")
    return path


def _run(*args):
    return subprocess.run([sys.executable, "-m", "magcal", "qc", *map(str, args)],
                          capture_output=True, text=True)


@pytest.mark.parametrize("variant", ["complete", "missing_y", "renamed_uT"])
def test_spikes_of_an_incomplete_or_renamed_sensor_are_flagged_at_their_rows(tmp_path,
                                                                           variant):
    kw = {"missing_y": {"drop": ["fgmo_y"]},
          "renamed_uT": {"rename": {f"fgmo_{c}": f"fgmo_{c}_uT" for c in "xyz"}}}
    path = _write(tmp_path, f"{variant}.csv", **kw.get(variant, {}))
    res = check_files([path])
    assert np.flatnonzero(res.result.flags & 1).tolist() == SPIKES.tolist()
    assert res.result.by_sensor["fgmo"] == {"spike": SPIKES.size}
    summary = res.to_json()
    assert set(summary["checked"]) == {"fgmo", "fgmi"}
    if variant == "missing_y":
        assert summary["checked"]["fgmo"] == ["fgmo_x", "fgmo_z"]
        assert summary["incomplete"] == {"fgmo": ["fgmo_y"]}
    if variant == "renamed_uT":
        assert summary["units"] == {"fgmo": "uT"}


def test_the_cli_names_the_incomplete_sensor_and_lists_what_it_checked(tmp_path):
    path = _write(tmp_path, "missing.csv", drop=["fgmo_y"])
    out = tmp_path / "q.csv"
    r = _run(path, "-o", out)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["n_flagged"] == SPIKES.size              # was 0: fgmo skipped
    assert summary["by_sensor"]["fgmo"] == {"spike": SPIKES.size}
    assert summary["checked"]["fgmo"] == ["fgmo_x", "fgmo_z"]
    assert "'fgmo' has no column fgmo_y" in r.stderr
    q = pd.read_csv(out, comment="#")
    assert np.flatnonzero(q["quality"].to_numpy() & 1).tolist() == SPIKES.tolist()


def test_a_declared_range_in_nt_refuses_a_sensor_in_another_unit(tmp_path):
    path = _write(tmp_path, "ut.csv", rename={f"fgmo_{c}": f"fgmo_{c}_uT" for c in "xyz"})
    out = tmp_path / "q.csv"
    r = _run(path, "-o", out, "--range-nt", "60000")
    assert r.returncode == 2
    assert "fgmo_x_uT" in r.stderr and "uT" in r.stderr
    assert not out.exists()


def test_field_columns_group_partial_and_suffixed_sets_and_list_the_rest():
    fc = FieldColumns.of(["Hp", "Hn", "b_total", "phase", "fgmo_x", "fgmo_y", "fgmo_z",
                          "fgmo_x_nT", "fgmo_y_nT", "fgmo_z_nT", "Hp_std"])
    assert [c for c, _ in fc.columns[""]] == ["Hp", "Hn"]
    assert fc.missing == {"": ["He"]}
    assert [c for c, _ in fc.columns["fgmo_nt"]] == ["fgmo_x_nT", "fgmo_y_nT", "fgmo_z_nT"]
    assert fc.not_checked == ["b_total", "phase", "Hp_std"]
