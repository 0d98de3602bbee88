"""Sensor-to-common rotations estimated against a reference field, with known truth."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from magcal.errors import InputError
from magcal.frames.estimate import estimate_rotation


def _field(rng, n=3000, variation=30.0):
    """A reference field whose direction varies (as over a day at geostationary orbit)."""
    t = np.linspace(0, 2 * np.pi, n)
    return np.column_stack([variation * np.cos(t), variation * np.sin(2 * t),
                            100 + 0.5 * variation * np.sin(t)]) + rng.normal(0, 0.05, (n, 3))


def test_rotation_and_offset_recovered(rng):
    ref = _field(rng)
    true_r = Rotation.from_euler("ZYX", [120, -35, 10], degrees=True)
    offset = np.array([20.0, -35.0, 70.0])
    sensor = true_r.inv().apply(ref) + offset  # ref = R (sensor - offset)
    sensor = sensor + rng.normal(0, 0.05, sensor.shape)  # the sensor's own noise
    fit = estimate_rotation(sensor, ref)
    assert fit.fit_offset
    np.testing.assert_allclose(fit.offset_nT, offset, atol=0.05)
    angle = np.degrees((Rotation.from_matrix(fit.matrix) * true_r.inv()).magnitude())
    assert angle < 0.05
    assert fit.rms_nT < 0.1 < 10 < fit.rms_rotation_only_nT
    # the stated uncertainty covers the error (noise 0.05 nT on a 100 nT field)
    assert angle < 5 * np.linalg.norm(fit.angle_std_deg)


def test_rotation_only_when_no_offset(rng):
    ref = _field(rng)
    true_r = Rotation.from_euler("ZYX", [-90, 180, 0], degrees=True)
    fit = estimate_rotation(true_r.inv().apply(ref), ref)
    assert not fit.fit_offset and np.allclose(fit.offset_nT, 0)
    np.testing.assert_allclose(fit.matrix, true_r.as_matrix(), atol=1e-4)


def test_nearly_constant_field_is_flagged_as_poorly_conditioned(rng):
    ref = _field(rng, variation=1.0)
    sensor = Rotation.from_euler("Z", 40, degrees=True).inv().apply(ref) + [5, 5, 5]
    good = estimate_rotation(_field(rng), _field(rng))
    poor = estimate_rotation(sensor, ref, fit_offset=True)
    assert poor.condition > 30 * good.condition
    assert poor.field_variation_nT < 2.0


def test_too_few_samples_is_a_clear_error():
    with pytest.raises(InputError, match="need 10"):
        estimate_rotation(np.ones((5, 3)), np.ones((5, 3)))
    with pytest.raises(InputError, match=r"\(n, 3\)"):
        estimate_rotation(np.ones((20, 3)), np.ones((20, 2)))
