"""Products worse than raw are said so (issue 13 case 5) and G is added back (case 7).

Synthetic two-sensor record with known truth: a slow disturber ``S u`` (variance 25) seen
3x stronger by the reference, which also carries 2 nT white noise ``n`` and a 500 nT
steady field along x. The regression gradiometer's matrix is, in closed form,
``K = 2 var(S) / (4 var(S) + 4) u u^T = 0.4808 u u^T``: it leaves ``0.0385 S u`` of the
disturber (low frequencies better) and injects ``-K n`` (high frequencies worse), and its
DC offset is ``G = 500 K x = 144.2 u``.
"""

import json

import numpy as np
import pandas as pd
from numpy.testing import assert_allclose

from magcal.ac.bandcheck import band_check
from magcal.cli import main


def _record(tmp_path, rng):
    n = 20000
    s = 5.0 * np.convolve(rng.normal(size=n), np.ones(200) / np.sqrt(200), mode="same")
    u = np.array([0.6, 0.0, 0.8])
    amb = np.array([120.0, -40.0, 15.0]) + 0.01 * rng.normal(size=(n, 3))
    target = amb + s[:, None] * u
    ref = amb + 3.0 * s[:, None] * u + 2.0 * rng.normal(size=(n, 3)) + [500.0, 0.0, 0.0]
    idx = pd.date_range("2020-01-01", periods=n, freq="100ms")
    cols = {f"o_{c}": target[:, k] for k, c in enumerate("xyz")}
    cols.update({f"r_{c}": ref[:, k] for k, c in enumerate("xyz")})
    df = pd.DataFrame(cols, index=idx.strftime("%Y-%m-%dT%H:%M:%S.%f"))
    df.index.name = "time"
    path = tmp_path / "in.csv"
    df.to_csv(path)
    plan = tmp_path / "plan.toml"
    plan.write_text('target = "o"\n[[stage]]\nregression = ["o"]\nreferences = ["r"]\n')
    return path, plan, target, amb


def s_of(target, amb):
    """The injected disturber's time series ``S`` (the target minus the ambient, along u)."""
    return (target - amb) @ np.array([0.6, 0.0, 0.8])


def test_worse_bands_are_recorded_and_warned(tmp_path, capsys):
    path, plan, target, amb = _record(tmp_path, np.random.default_rng(11))
    params, clean = tmp_path / "p.json", tmp_path / "c.csv"
    assert main(["picog", "fit", str(path), "--plan", str(plan), "-o", str(params)]) == 0
    err = capsys.readouterr().err
    doc = json.loads(params.read_text())
    # -K n: 0.96 nT along u against 0.01 nT raw: x and z worse at high frequency
    worse = doc["worse_than_raw"]
    assert {w["component"] for w in worse} >= {"x", "z"}
    assert min(w["band_hz"][0] for w in worse) > 0.05
    assert "worse than raw" in err and "worse_than_raw" in err
    # the on-board product (constant matrices) on request: delivered as it is, warned
    assert main(["picog", "apply", str(path), "--params", str(params), "--on-board",
                 "-o", str(clean)]) == 0
    apply_err = capsys.readouterr().err                  # the delivered product is checked
    assert "worse than raw" in apply_err and "|G|" in apply_err
    out = pd.read_csv(clean)[["x", "y", "z"]].to_numpy()
    # the disturber (20 s boxcar-filtered noise: its power is below 0.05 Hz) is removed
    chk = band_check(target, out, 0.1)
    low = [k for k, (lo, hi) in enumerate(chk.bands_hz) if lo < 0.02]
    assert low and np.all(chk.reduction[low][:, [0, 2]] > 10)
    resid = out - amb
    k = 50.0 / 104.0
    remnant = np.sqrt((2 * k) ** 2 + (1 - 2 * k) ** 2 * np.var(s_of(target, amb)))
    assert_allclose(np.std(resid, axis=0)[[0, 2]], remnant * np.array([0.6, 0.8]), rtol=0.08)
    # default product: sum M B + G keeps the target's mean field (the reference's
    # 500 nT steady field does not leak in); G is large against the field -> warned
    assert_allclose(np.mean(out, axis=0), np.mean(target, axis=0), atol=1e-6)
    assert "|G|" in err


def test_keep_correction_offset_gives_the_bare_sum(tmp_path, capsys):
    path, plan, target, _ = _record(tmp_path, np.random.default_rng(12))
    params = tmp_path / "p.json"
    assert main(["picog", "fit", str(path), "--plan", str(plan), "-o", str(params)]) == 0
    doc = json.loads(params.read_text())
    G = np.array(doc["G"])
    frame = pd.read_csv(path)
    bare = sum(frame[[f"{s}_x", f"{s}_y", f"{s}_z"]].to_numpy() @ np.array(m).T
               for s, m in doc["M"].items())
    outs = {}
    for flag in ("--keep-correction-offset", "--pure-ac", None):
        o = tmp_path / f"{flag}.csv"
        argv = ["picog", "apply", str(path), "--params", str(params), "--on-board",
                "-o", str(o)]
        assert main(argv + ([flag] if flag else [])) == 0
        outs[flag] = pd.read_csv(o)[["x", "y", "z"]].to_numpy()
    assert_allclose(outs["--keep-correction-offset"], bare, atol=1e-5)
    assert_allclose(outs[None], bare + G, atol=1e-5)
    assert_allclose(outs["--pure-ac"], outs[None], atol=1e-9)
    assert_allclose(G, 500 * 50 / 104 * 0.6 * np.array([0.6, 0.0, 0.8]), atol=4.0)


def test_records_auto_cannot_support_are_refused(tmp_path, capsys):
    path, plan, _, _ = _record(tmp_path, np.random.default_rng(13))
    frame = pd.read_csv(path)
    short = tmp_path / "short.csv"
    frame.iloc[:100].to_csv(short, index=False)
    out = tmp_path / "p.json"
    assert main(["picog", "fit", str(short), "--target", "o", "--auto", "-o", str(out)]) == 2
    assert "100 samples" in capsys.readouterr().err and not out.exists()
    # a plan still fits, but says that the product could not be checked by band
    assert main(["picog", "fit", str(short), "--plan", str(plan), "-o", str(out)]) == 0
    assert "no band check" in capsys.readouterr().err
    empty = tmp_path / "empty.csv"
    frame.assign(r_y=np.nan).to_csv(empty, index=False)
    for argv in (["--target", "o", "--auto"], ["--plan", str(plan)]):
        assert main(["picog", "fit", str(empty), *argv, "-o", str(tmp_path / "e.json")]) == 2
        err = capsys.readouterr().err
        assert "r_y" in err and "empty.csv" in err and "Traceback" not in err
        assert "Warning" not in err
