"""GOES-16 L2 minutes through ``magcal run`` end to end (real data).

The two sensors come in their own frames and the per-sensor BRF/EPN variables are fill,
so the sensor-to-BRF rotations are estimated against the file's combined ``b_brf`` and
the BRF-to-Hpen rotation against the file's ``b_epn``. What the numbers are checked
against, read off the files independently of the fit:

* ``dn_...v2_0_0`` (2017-04-14): the combined ``b_brf`` is the outboard sensor rotated
  (NOAA's v2 processing), so a pure rotation must reproduce it to the float32
  resolution of the file and the sensor noise (< 0.1 nT rms);
* ``dr_...v1_0_1`` (2017-03-05): the combined field differs from either sensor by tens
  of nT in magnitude (|b_brf| - |b_ob| is 11 nT), so a rotation alone cannot fit it
  (> 5 nT rms) and rotation plus offset must (< 0.5 nT rms);
* the file's EPN and BRF vectors are both NOAA products of the same combined field:
  the Hpen of the product must reproduce ``b_epn`` to 0.5 nT (0.25 deg of a 120 nT
  field);
* minutes of data cannot give a 28-day offset or an alignment: the products must say
  so (reasons), and discovery on a handful of 1-min samples fails with its reason
  (exit status 3: some stages failed). The alignment runs on every 10 Hz sample (``kp_max =
  9``: no minute is at Kp <= 1) and must report the rotation as not determinable: a
  few minutes of a nearly constant field cannot separate a rotation from the offset it
  fits.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from magcal.cli import main
from conftest import real_data_path

# one test process for the whole module (pyproject runs pytest with --dist loadgroup):
# its module fixtures (GOES chain runs, 7-13 s each) are then computed once instead of
# once per process
pytestmark = pytest.mark.xdist_group("chain_goes")

KP = "indices/celestrak_SW_2017-2023_subset.txt"


def _config(tmp_path, folder: str) -> Path:
    files = real_data_path("goes16", folder)
    kp = real_data_path(*KP.split("/"))
    text = f"""
[input]
files = ["{files.as_posix()}/*.nc"]
target = "ob"
sensors = ["ob", "ib"]
frame = "brf"
[frames]
to_common = {{ ob = "estimate", ib = "estimate" }}
reference = "brf"
to_hpen = "estimate"
[position]
columns = true
[kp]
file = "{kp.as_posix()}"
[picog]
plan = "auto"
[alignment]
kp_max = 9.0
cadence_s = 0
[report]
enabled = false
"""
    path = tmp_path / "CHAIN.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module", params=["l2_hires_gap", "l2_hires_5min"])
def goes_run(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp(request.param)
    cfg = _config(tmp, request.param)
    out = tmp / "out"
    status = main(["run", str(cfg), "-o", str(out), "--quiet"])
    load = lambda *p: json.loads(out.joinpath(*p).read_text())  # noqa: E731
    return request.param, status, out, load


def test_sensor_rotations_reproduce_the_combined_field(goes_run):
    folder, _, _, load = goes_run
    ob = load("frames", "FRAMES.json")["sensors"]["ob"]
    if folder == "l2_hires_gap":
        assert ob["rms_rotation_only_nT"] < 0.1 and not ob["fit_offset"]
    else:
        assert ob["rms_rotation_only_nT"] > 5.0
        assert ob["fit_offset"] and ob["rms_nT"] < 0.5
    R = np.asarray(ob["matrix"])
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-9)


def test_hpen_reproduces_the_files_epn(goes_run):
    _, _, _, load = goes_run
    frames = load("frames", "FRAMES.json")
    assert frames["to_hpen"]["check_rms_nT"] < 0.5
    ac = load("ac", "AC.json")
    assert ac["hpen_vs_input_rms_nT"] < 0.5


def test_picog_says_what_it_removes_and_never_delivers_worse(goes_run):
    _, _, _, load = goes_run
    ac = load("ac", "AC.json")
    assert ac["removed_rms_nT"] >= 0.0 and ac["identity_error"] < 1e-12
    if ac["n_bands_worse"]:
        # the constant matrices were worse in some band: the uncleaned target, or a
        # band-selective product whose own check found no band worse than raw
        ground = load("ac", "PARAMS.json")["ground"]
        assert ac["delivered"] == "raw" or (
            ac["product"] in ("ground", "band_limited") and ground["worse_than_raw"] == []
            and ground["delivered"] == ac["product"]), (ac["delivered"], ac.get("product"))
        assert any("worse than raw" in w for w in ac["warnings"])
        if ac["delivered"] != "raw":
            # said of the product delivered, not only of the constant matrices (the line
            # read "13 band/component(s) worse than raw" for a product worse in none)
            assert ac["n_bands_worse_delivered"] == 0


def test_minutes_cannot_give_a_28_day_offset_and_the_products_say_so(goes_run):
    _, status, out, load = goes_run
    assert status == 3  # discovery cannot run on a handful of 1-min samples
    manifest = load("MANIFEST.json")
    failed = {f["stage"]: f["reason"] for f in manifest["failed"]}
    assert set(failed) == {"discover"} and "samples" in failed["discover"]
    align = load("alignment", "ALIGN.json")
    assert align["determinable"] is False and align["reason"]
    offsets = (out / "offsets" / "OFFSETS.csv").read_text()
    assert "far shorter than the 28-day window" in offsets
    assert any("far shorter" in w for w in manifest["warnings"])


def test_sensors_in_their_own_frames_without_rotations_are_refused(tmp_path, capsys):
    files = real_data_path("goes16", "l2_hires_gap")
    cfg = tmp_path / "CHAIN.toml"
    cfg.write_text(f'[input]\nfiles = ["{files.as_posix()}/*.nc"]\ntarget = "ob"\n'
                   'sensors = ["ob", "ib"]\n[position]\ncolumns = true\n')
    assert main(["run", str(cfg), "-o", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "each in their own frame" in err and "to_common" in err
