"""Forked chunk sharing for the model field (magcal.models.parallel)."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from magcal.models import irbem
from magcal.models.field import model_field_hpen
from magcal.models.parallel import evaluate_parallel, fork_available, run_shared, shared_array
from magcal.frames.hpen import hpen_basis

needs_fork = pytest.mark.skipif(not fork_available(), reason="no fork on this platform")


@needs_fork
def test_every_item_done_once_and_children_write_shared_memory():
    out = shared_array(200)
    who = shared_array(200, np.int64)
    parent = os.getpid()

    def work(i):
        out[i] += i + 0.5  # += : an item done twice would show
        who[i] = os.getpid()
        time.sleep(0.002)  # long enough for the child to start and take its share

    assert run_shared(200, work, n_jobs=2) == 0
    assert_array_equal(out, np.arange(200) + 0.5)
    assert np.any(who != parent)  # the child took some items...
    assert np.any(who == parent)  # ...and so did the caller


@needs_fork
def test_items_of_a_crashed_child_are_redone_by_the_caller():
    out = shared_array(50)
    parent = os.getpid()

    def work(i):
        if os.getpid() != parent:
            os._exit(3)  # the child dies on its first item without finishing it
        out[i] = 2.0 * i
        time.sleep(0.002)

    redone = run_shared(50, work, n_jobs=2)
    assert redone >= 1
    assert_array_equal(out, 2.0 * np.arange(50))


@needs_fork
def test_an_error_in_work_reaches_the_caller():
    def work(i):
        if i == 7:
            raise ValueError("item 7 is bad")

    with pytest.raises(ValueError, match="item 7"):
        run_shared(20, work, n_jobs=2)


def _year_of_minutes(n):
    t = np.datetime64("2019-03-01T00:00", "ns") + np.arange(n) * np.timedelta64(60, "s")
    kp = np.where(np.arange(n) % 1000 == 5, 9.5, 1.0)  # out of range for T89 -> NaN
    return t, kp


@needs_fork
def test_parallel_with_worker_transform_equals_serial_geo_rotated():
    n = 40_000
    t, kp = _year_of_minutes(n)
    xyz = irbem.geo_position_re(128.2, 0.0, 6.6)[0]
    ser = irbem.evaluate_geo(t, xyz, "T89", {"Kp": kp})
    basis_t = hpen_basis(128.2, 0.0)[0].T
    b, invalid, reasons, backend = evaluate_parallel(
        t, xyz, "T89", {"Kp": kp}, None, n_jobs=2, transform=lambda idx, g: g @ basis_t)
    assert backend == "ctypes"
    assert_array_equal(invalid, ser.invalid)
    assert int(invalid.sum()) == 40 and reasons == ser.reasons
    assert np.all(np.isnan(b[invalid]))
    assert_allclose(b[~invalid], ser.b_geo_nT[~invalid] @ basis_t, rtol=0, atol=1e-9)


@needs_fork
def test_cached_product_written_in_place_is_private_and_identical(tmp_path):
    n = 30_000
    t, kp = _year_of_minutes(n)
    first = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=kp, n_jobs=2, cache_dir=tmp_path)
    serial = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=kp, n_jobs=1)
    assert_array_equal(first.b_hpen_nT, serial.b_hpen_nT)
    assert first.n_invalid == 30
    # the returned array is writable, and writing to it does not touch the cache entry
    keep = first.b_hpen_nT[0].copy()
    first.b_hpen_nT[0] = 0.0
    again = model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=kp, n_jobs=2, cache_dir=tmp_path)
    assert again.cache_hits == 1
    assert_array_equal(again.b_hpen_nT[0], keep)
    assert_array_equal(again.b_hpen_nT[1:], serial.b_hpen_nT[1:])
    assert not list(tmp_path.glob(".*.part"))  # no temporary file left behind


def test_failed_request_leaves_no_partial_cache_file(tmp_path, monkeypatch):
    import magcal.models.field as field

    def broken(*args, out=None, **kwargs):
        out[:5] = 1.0  # a worker had started writing into the cache file
        raise RuntimeError("IRBEM failed")

    monkeypatch.setattr(field, "evaluate_parallel", broken)
    t, kp = _year_of_minutes(30_000)
    with pytest.raises(RuntimeError, match="IRBEM failed"):
        model_field_hpen(t, 128.2, 0.0, 6.6, "T89", kp=kp, n_jobs=2, cache_dir=tmp_path)
    assert [p.name for p in tmp_path.rglob("*") if p.is_file()] == []
