"""Frames: sensor matrices, geocentric rotations, Hpen, against closed forms and GOES-16 files."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from magcal.errors import InputError
from magcal.frames import (
    SensorFrames,
    check_rotation,
    convert_vectors,
    from_common,
    geo_to_hpen,
    hpen_basis,
    hpen_to,
    llr_from_geo,
    osrf_to_hpen,
    position_geo,
    rotation_from_euler,
    rotation_matrices,
    to_common,
    to_hpen,
)


def _random_times(rng, n):
    start = pd.Timestamp("2017-01-01T00:00:00Z").value
    stop = pd.Timestamp("2020-12-31T00:00:00Z").value
    stamps = rng.integers(start, stop, n).astype("datetime64[ns]")
    return pd.DatetimeIndex(stamps).tz_localize("UTC")


def _random_vectors(rng, n):
    return rng.normal(size=(n, 3)) * rng.uniform(1.0, 500.0, size=(n, 1))


# --- geocentric frames --------------------------------------------------------------

@pytest.mark.parametrize("frame", ["GSM", "GSE", "GEI", "SM"])
def test_round_trip_geo_frame_geo(frame, rng):
    times = _random_times(rng, 400)
    b = _random_vectors(rng, 400)
    there = convert_vectors(b, times, "GEO", frame)
    back = convert_vectors(there, times, frame, "GEO")
    scale = np.linalg.norm(b, axis=1, keepdims=True)
    assert_allclose((back - b) / scale, 0.0, atol=1e-9)
    # and the map is not the identity (a test that cannot fail would pass that too)
    assert np.abs((there - b) / scale).max() > 1e-2


@pytest.mark.parametrize("frame", ["GEO", "GSM", "GSE"])
def test_round_trip_through_hpen(frame, rng):
    times = _random_times(rng, 300)
    b = _random_vectors(rng, 300)
    lon = rng.uniform(-180, 180, 300)
    lat = rng.uniform(-10, 10, 300)
    hpen = to_hpen(b, times, lon, lat, frame)
    back = hpen_to(hpen, times, lon, lat, frame)
    scale = np.linalg.norm(b, axis=1, keepdims=True)
    assert_allclose((back - b) / scale, 0.0, atol=1e-9)
    assert_allclose(np.linalg.norm(hpen, axis=1), scale[:, 0], rtol=1e-4)  # GSE: 3e-5


def test_matrices_equal_spacepy_position_conversion(rng):
    """Columns convention: M @ p equals spacepy/IRBEM converting the position p itself."""
    import spacepy.coordinates as spc
    from spacepy.time import Ticktock

    times = pd.DatetimeIndex(["2017-03-05T02:09:00", "2017-04-14T19:24:00",
                              "2019-06-21T12:00:00"])
    pos = position_geo([-89.5, 128.2, 10.0], [0.0, 3.0, -20.0], [6.6, 6.6, 2.0])
    for frame in ("GSM", "GSE", "GEI"):
        coords = spc.Coords(pos, "GEO", "car", units=["Re"] * 3, use_irbem=True)
        coords.ticks = Ticktock(times.to_pydatetime(), "UTC")
        expected = coords.convert(frame, "car").data
        assert_allclose(convert_vectors(pos, times, "GEO", frame), expected, rtol=0, atol=1e-12)


def test_sub_second_times_use_nearest_whole_second():
    times = pd.DatetimeIndex(["2017-03-05T02:09:00.4", "2017-03-05T02:09:00.6",
                              "2017-03-05T02:09:01.0", "2017-03-05T02:09:00"])
    m = rotation_matrices(times, "GEO", "GEI")
    assert_array_equal(m[0], m[3])
    assert_array_equal(m[1], m[2])
    # one second of Earth rotation about z: 7.2921e-5 rad between the two
    step = m[1] @ m[0].T
    assert_allclose(abs(np.arctan2(step[1, 0], step[0, 0])), 7.2921e-5, rtol=1e-4)
    assert_allclose(step[2], [0.0, 0.0, 1.0], atol=1e-15)


def test_sm_axis_is_igrf13_dipole_axis():
    """IRBEM's SM z axis is the IGRF-13 centred dipole of mid-2017 for any 2017 date.

    IGRF-13: DGRF 2015 g10, g11, h11 = -29441.46, -1501.77, 4795.99 nT; IGRF 2020
    -29404.8, -1450.9, 4652.5 nT; linear in time. The northern dipole axis is
    -(g11, h11, g10)/|.|, here at 2017.5.
    """
    f = 0.5
    g10 = -29441.46 + f * (-29404.8 + 29441.46)
    g11 = -1501.77 + f * (-1450.9 + 1501.77)
    h11 = 4795.99 + f * (4652.5 - 4795.99)
    axis = -np.array([g11, h11, g10]) / np.linalg.norm([g11, h11, g10])
    for t in ["2017-01-01T00:00:00", "2017-04-14T19:24:00", "2017-12-31T23:00:00"]:
        z = convert_vectors([0.0, 0.0, 1.0], [t], "SM", "GEO")[0]
        assert np.rad2deg(np.arccos(min(1.0, z @ axis))) < 1e-3
    # GSM z lies in the plane of the dipole axis and GSM x (the Sun): y_SM = y_GSM
    for t in ["2017-04-14T19:24:00", "2019-06-21T12:00:00"]:
        y = convert_vectors([0.0, 1.0, 0.0], [t], "GSM", "SM")[0]
        assert_allclose(y, [0.0, 1.0, 0.0], atol=1e-12)


def test_gse_x_points_at_the_sun_like_astropy():
    from astropy.coordinates import ITRS, get_sun
    from astropy.time import Time

    for t in ["2017-03-05T02:09:00", "2017-04-14T19:24:00", "2019-06-21T12:00:00"]:
        when = Time(t, scale="utc")
        sun = get_sun(when).transform_to(ITRS(obstime=when)).cartesian.xyz.value
        sun = sun / np.linalg.norm(sun)
        x = convert_vectors([1.0, 0.0, 0.0], [t], "GSE", "GEO")[0]
        x = x / np.linalg.norm(x)
        # IRBEM's low-precision Sun: 10-25 arcsec from astropy's apparent Sun here
        assert np.rad2deg(np.arccos(min(1.0, x @ sun))) * 3600 < 60.0


# --- Hpen closed forms --------------------------------------------------------------

def _dipole(m, r):
    """Field of a centred dipole (mu0/4pi = 1): (3 (m.rhat) rhat - m) / r^3."""
    rn = np.linalg.norm(r, axis=1, keepdims=True)
    rhat = r / rn
    return (3 * np.sum(m * rhat, axis=1, keepdims=True) * rhat - m) / rn ** 3


def test_dipole_along_minus_z_geo_in_hpen():
    """m = -M z_GEO: Hp = M cos(lat)/r^3, He = 2 M sin(lat)/r^3, Hn = 0 (equator: all Hp)."""
    moment = 8.0e4
    lon = np.array([-89.5, 0.0, 45.0, 128.2, 180.0, -150.0, 10.0])
    lat = np.array([0.0, 0.0, 0.0, 5.0, -8.0, 30.0, -60.0])
    r = np.array([6.6, 6.6, 1.0, 6.6, 3.0, 4.0, 2.0])
    pos = position_geo(lon, lat, r)
    b_geo = _dipole(np.array([[0.0, 0.0, -moment]]), pos)
    expected = np.stack([moment * np.cos(np.deg2rad(lat)) / r ** 3,
                         2 * moment * np.sin(np.deg2rad(lat)) / r ** 3, np.zeros_like(r)], axis=1)
    hpen = geo_to_hpen(b_geo, lon, lat)
    assert_allclose(hpen, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    assert_allclose(hpen[:3], [[moment / 6.6 ** 3, 0, 0], [moment / 6.6 ** 3, 0, 0],
                               [moment, 0, 0]], atol=1e-9 * moment)


def test_dipole_evaluated_in_gsm_gives_the_same_hpen(rng):
    """The same dipole, evaluated with moment and position rotated into GSM, then to Hpen."""
    moment = 3.0e4
    n = 50
    times = _random_times(rng, n)
    lon = rng.uniform(-180, 180, n)
    lat = rng.uniform(-20, 20, n)
    r = np.full(n, 6.6)
    m_gsm = convert_vectors(np.tile([0.0, 0.0, -moment], (n, 1)), times, "GEO", "GSM")
    pos_gsm = convert_vectors(position_geo(lon, lat, r), times, "GEO", "GSM")
    b_gsm = _dipole(m_gsm, pos_gsm)
    expected = np.stack([moment * np.cos(np.deg2rad(lat)) / r ** 3,
                         2 * moment * np.sin(np.deg2rad(lat)) / r ** 3, np.zeros(n)], axis=1)
    assert_allclose(to_hpen(b_gsm, times, lon, lat, "GSM"), expected, rtol=0,
                    atol=1e-9 * np.abs(expected).max())


def test_hpen_basis_is_left_handed_and_orthonormal(rng):
    basis = hpen_basis(rng.uniform(-180, 180, 20), rng.uniform(-80, 80, 20))
    gram = np.einsum("nij,nkj->nik", basis, basis)
    assert_allclose(gram, np.broadcast_to(np.eye(3), basis.shape), atol=1e-14)
    assert_allclose(np.linalg.det(basis), -1.0, atol=1e-14)
    assert_allclose(np.cross(basis[:, 0], basis[:, 1]), -basis[:, 2], atol=1e-14)


def test_positions():
    pos = position_geo([-89.5, 128.2], [0.0, 10.0], [6.6, 2.0])
    assert_allclose(pos[0], [6.6 * np.cos(np.deg2rad(-89.5)), 6.6 * np.sin(np.deg2rad(-89.5)), 0.0])
    lon, lat, r = llr_from_geo(pos)
    assert_allclose(lon, [-89.5, 128.2], atol=1e-12)
    assert_allclose(lat, [0.0, 10.0], atol=1e-12)
    assert_allclose(r, [6.6, 2.0], atol=1e-12)


def test_osrf_to_hpen_matches_sosmag_section_5_1():
    """GK-2A nominal attitude: Hp = By_OSRF, He = Bx_OSRF, Hn = Bz_OSRF."""
    b = np.array([[1.0, 2.0, 3.0], [-4.0, 5.0, -6.0]])
    assert_array_equal(osrf_to_hpen(b), [[2.0, 1.0, 3.0], [5.0, -4.0, -6.0]])


def test_frame_errors():
    with pytest.raises(InputError, match="unknown frame 'HEE'"):
        convert_vectors([1.0, 0, 0], ["2017-01-01"], "GEO", "HEE")
    with pytest.raises(InputError, match="2 vectors but 1 times"):
        convert_vectors(np.ones((2, 3)), ["2017-01-01"], "GEO", "GSM")
    with pytest.raises(InputError, match="NaT"):
        convert_vectors(np.ones((1, 3)), [None], "GEO", "GSM")


def test_nan_vectors_stay_nan():
    out = convert_vectors([[np.nan, 1.0, 1.0], [1.0, 1.0, 1.0]],
                          ["2017-01-01T00:00:00", "2017-01-01T00:00:01"], "GEO", "GSM")
    assert np.isnan(out[0]).all() and np.isfinite(out[1]).all()


# --- GOES-16: the file's EPN, GSE, GSM and ECI against our transforms -----------------

@pytest.mark.parametrize("folder", ["l2_hires_5min", "l2_hires_gap"])
def test_goes16_epn_gse_gsm_agree_with_our_transforms(folder, real_data):
    from magcal.missions.goes import read_goes_mag

    df = read_goes_mag(real_data("goes16", folder))
    hpen = df[["Hp", "He", "Hn"]].to_numpy()
    lon, lat = df["lon_deg"].to_numpy(), df["lat_deg"].to_numpy()
    worst = {}
    for frame in ("GSE", "GSM"):
        b = df[[f"{frame.lower()}_{c}" for c in "xyz"]].to_numpy()
        from_file = to_hpen(b, df.index, lon, lat, frame)
        back = hpen_to(hpen, df.index, lon, lat, frame)
        worst[frame] = (np.abs(from_file - hpen).max(), np.abs(back - b).max())
        assert np.abs(from_file - hpen).max() < 0.5, (frame, worst)
        assert np.abs(back - b).max() < 0.5, (frame, worst)
    # the file's ECI is IRBEM's GEI of date: same field to float32 precision
    eci = convert_vectors(df[["gse_x", "gse_y", "gse_z"]].to_numpy(), df.index, "GSE", "GEI")
    assert_allclose(eci, df[["eci_x", "eci_y", "eci_z"]].to_numpy(), rtol=0, atol=2e-3)
    # and the check can fail: the wrong EPN order (E, P, N as Hp, He, Hn) is far off
    swapped = hpen[:, [1, 0, 2]]
    b = df[["gse_x", "gse_y", "gse_z"]].to_numpy()
    assert np.abs(to_hpen(b, df.index, lon, lat, "GSE") - swapped).max() > 30.0


# --- sensor frames ------------------------------------------------------------------

def test_euler_matches_closed_form():
    a, b, c = np.deg2rad([30.0, -20.0, 10.0])
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rx = np.array([[1, 0, 0], [0, np.cos(c), -np.sin(c)], [0, np.sin(c), np.cos(c)]])
    assert_allclose(rotation_from_euler([30.0, -20.0, 10.0], "ZYX"), rz @ ry @ rx, atol=1e-14)
    assert_allclose(rotation_from_euler([30.0, -20.0, 10.0], "zyx"), rx @ ry @ rz, atol=1e-14)


def test_sensor_frames_round_trip_and_checks(rng):
    rot = rotation_from_euler([12.0, 3.0, -40.0])
    calib = np.array([[1.02, 0.01, -0.003], [0.0, 0.98, 0.02], [0.004, 0.0, 1.01]]) @ rot
    frames = SensorFrames({"fgmi": rot, "fgmo": np.eye(3)}, common="fgmo")
    b = _random_vectors(rng, 100)
    assert_allclose(frames.to_common("fgmi", b), b @ rot.T, atol=1e-12)
    assert_allclose(frames.from_common("fgmi", frames.to_common("fgmi", b)), b, atol=1e-10)
    common = frames.all_to_common({"fgmi": b, "fgmo": b})
    assert_allclose(common["fgmo"], b)
    assert frames.names == ("fgmi", "fgmo")
    with pytest.raises(InputError, match=r"column M\[amr1\]: matrix is not orthonormal"):
        SensorFrames({"amr1": calib})
    general = SensorFrames({"amr1": calib}, orthonormal=False)
    assert_allclose(general.from_common("amr1", to_common(b, calib)), b, rtol=1e-12, atol=1e-9)
    assert_allclose(from_common(to_common(b, calib), calib), b, rtol=1e-12, atol=1e-9)
    with pytest.raises(InputError, match="reflection"):
        check_rotation(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(InputError, match="singular"):
        SensorFrames({"x": np.zeros((3, 3))}, orthonormal=False)
    with pytest.raises(InputError, match="3x3"):
        check_rotation(np.eye(2))
    with pytest.raises(InputError, match="no frame matrix for sensor 'amr2'"):
        frames.to_common("amr2", b)
    with pytest.raises(TypeError):
        frames.matrices["new"] = np.eye(3)
    assert frames.as_dict()["M"]["fgmo"] == np.eye(3).tolist()
