"""``[output] format`` of ``magcal run`` (issue 23): the corrected days and the offset
product in CF netCDF4 or ISTP CDF equal the CSV run's products at the CSV's written
precision, are listed in MANIFEST.json with their checksums, and a rerun skips them.

The archive is a small simulation (4 days at 1-min cadence): each run takes seconds."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from magcal.chain import read_chain_config, run_chain
from magcal.chain.config import parse_chain_config
from magcal.chain.output import product_format
from magcal.errors import InputError
from magcal.io.products import read_product
from magcal.provenance import file_sha256

CHAIN = """
[input]
files = ["raw/day_*.csv"]
target = "fgmo"
sensors = ["fgmo", "fgmi"]
[position]
longitude_deg = 128.2
[kp]
file = "raw/kp.csv"
[picog]
plan = "none"
fit_days = 2
[offsets]
window_days = 2
step_days = 1
min_used = 100
[alignment]
enabled = false
[discover]
enabled = false
[report]
enabled = false
"""


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """One archive run per format on the same simulated raw files."""
    from magcal.chain.engine import Engine
    from magcal.simulate.archive import ArchiveConfig, simulate_archive, write_archive_files

    folder = tmp_path_factory.mktemp("formats")
    res = simulate_archive(ArchiveConfig(n_days=4, cadence_s=60.0, step_time="2019-11-03"),
                           rng=np.random.default_rng(11))
    write_archive_files(res, folder / "raw")
    out = {}
    with Engine(1) as engine:
        for fmt in ("csv", "netcdf", "cdf"):
            cfg = folder / f"CHAIN_{fmt}.toml"
            cfg.write_text(CHAIN + f'[output]\nformat = "{fmt}"\n')
            run_chain(read_chain_config(cfg), folder / fmt, engine=engine)
            out[fmt] = folder / fmt
        # the raw days as netCDF4 (read directly, no text): products in netCDF by default
        from magcal.io.formats import read_any, write_any

        (folder / "raw_nc").mkdir()
        for day in sorted((folder / "raw").glob("day_*.csv")):
            write_any(folder / "raw_nc" / f"{day.stem}.nc", read_any(day), "netcdf")
        cfg = folder / "CHAIN_nc_input.toml"
        cfg.write_text(CHAIN.replace('"raw/day_*.csv"', '"raw_nc/day_*.nc"'))
        run_chain(read_chain_config(cfg), folder / "nc_input", engine=engine)
        out["nc_input"] = folder / "nc_input"
        # a rerun of the netCDF run: nothing rewritten
        before = {p.name: file_sha256(p) for p in (folder / "netcdf" / "corrected").iterdir()}
        run_chain(read_chain_config(folder / "CHAIN_netcdf.toml"), folder / "netcdf",
                  engine=engine)
        out["rerun"] = (before, {p.name: file_sha256(p)
                                 for p in (folder / "netcdf" / "corrected").iterdir()})
    return out


def _assert_quality_is_a_flag_variable(path: Path, fmt: str) -> None:
    """The chain's quality column, seen by an independent reader, names qc's bits."""
    from magcal.qc.flags import FLAG_NAMES

    if fmt == "netcdf":
        import xarray as xr

        with xr.open_dataset(path, engine="h5netcdf") as ds:
            attrs = ds["quality"].attrs
            masks, meanings = attrs["flag_masks"], attrs["flag_meanings"]
    else:
        import cdflib

        attrs = cdflib.CDF(str(path)).varattsget("quality")
        assert attrs["VAR_TYPE"] == "support_data" and attrs["DEPEND_0"] == "Epoch"
        masks, meanings = attrs["FLAG_MASKS"], attrs["FLAG_MEANINGS"]
    assert [int(m) for m in masks] == list(FLAG_NAMES)
    assert meanings.split() == list(FLAG_NAMES.values())


@pytest.mark.parametrize("fmt,suffix", [("netcdf", ".nc"), ("cdf", ".cdf")])
def test_binary_products_equal_csv_products(runs, fmt, suffix):
    csv_days = sorted((runs["csv"] / "corrected").glob("CORRECTED_*.csv"))
    days = sorted((runs[fmt] / "corrected").glob("CORRECTED_*"))
    assert [p.name for p in days] == [p.with_suffix(suffix).name for p in csv_days]
    assert len(days) >= 4
    for a, b in zip(csv_days, days):
        ref, got = read_product(a), read_product(b)
        assert got.index.equals(ref.index)
        for c in ref.columns:  # every CSV column, as a variable of the same name
            np.testing.assert_allclose(got[c].to_numpy(float), ref[c].to_numpy(float),
                                       atol=5.1e-7, rtol=0, err_msg=f"{b.name} {c}")
    assert "quality" in ref.columns  # the QC bit flags of every sample (magcal.qc)
    _assert_quality_is_a_flag_variable(days[0], fmt)
    assert (runs[fmt] / "offsets" / "OFFSETS.csv").is_file()  # the contract's file stays
    got = read_product(runs[fmt] / "offsets" / f"OFFSETS{suffix}")
    from magcal.offsets import read_offsets_csv

    ref = read_offsets_csv(runs["csv"] / "offsets" / "OFFSETS.csv").to_frame()
    np.testing.assert_array_equal(got.index.tz_localize(None).to_numpy(), ref["center"])
    assert list(got.columns) == [c for c in ref.columns if c != "center"]
    for c in got.columns:  # OFFSETS.csv keeps 4 decimals and whole seconds
        if c in ("start", "end"):
            np.testing.assert_array_equal(got[c].dt.tz_localize(None).to_numpy(), ref[c])
        elif c == "reason":
            assert got[c].tolist() == list(ref[c])
        else:
            np.testing.assert_allclose(got[c].to_numpy(float, na_value=np.nan),
                                       ref[c].to_numpy(float, na_value=np.nan),
                                       atol=5.1e-5, rtol=0, err_msg=c)


@pytest.mark.parametrize("fmt,suffix", [("netcdf", ".nc"), ("cdf", ".cdf")])
def test_manifest_lists_binary_products_with_checksums(runs, fmt, suffix):
    doc = json.loads((runs[fmt] / "MANIFEST.json").read_text())
    listed = {p["path"]: p for p in doc["products"]}
    corrected = [p for p in listed if p.startswith("corrected/CORRECTED_")]
    assert corrected and all(p.endswith(suffix) for p in corrected)
    assert f"offsets/OFFSETS{suffix}" in listed
    for path, entry in listed.items():
        if path.endswith(suffix):
            assert entry["sha256"] == file_sha256(runs[fmt] / path)


def test_rerun_leaves_binary_products_untouched(runs):
    before, after = runs["rerun"]
    assert before == after and before


def test_format_default_is_the_input_family_and_bad_format_refused(tmp_path):
    base = '[input]\nfiles = ["x/*.nc"]\ntarget = "ob"\nformat = "{}"\n[position]\n' \
           'longitude_deg = -75.2\n'
    assert product_format(parse_chain_config(base.format("goes-netcdf"), tmp_path / "C.toml")
                          ) == "netcdf"
    assert product_format(parse_chain_config(base.format("cdf"), tmp_path / "C.toml")) == "cdf"
    assert product_format(parse_chain_config(base.format("csv"), tmp_path / "C.toml")) == "csv"
    chosen = base.format("goes-netcdf") + '[output]\nformat = "cdf"\n'
    assert product_format(parse_chain_config(chosen, tmp_path / "C.toml")) == "cdf"
    with pytest.raises(InputError, match=r"\[output\] format 'hdf5'"):
        parse_chain_config(base.format("csv") + '[output]\nformat = "hdf5"\n',
                           tmp_path / "C.toml")


def test_netcdf_input_read_directly_gives_the_same_products(runs):
    """Raw days as CF netCDF4 (``read_any``: no text on the way): the products default to
    netCDF and equal the CSV-input run's."""
    days = sorted((runs["nc_input"] / "corrected").glob("CORRECTED_*"))
    assert days and all(p.suffix == ".nc" for p in days)
    for p in days:
        ref = read_product(runs["csv"] / "corrected" / p.with_suffix(".csv").name)
        got = read_product(p)
        assert got.index.equals(ref.index)
        for c in ref.columns:
            np.testing.assert_allclose(got[c].to_numpy(float), ref[c].to_numpy(float),
                                       atol=5.1e-7, rtol=0)
