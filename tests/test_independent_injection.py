"""The independent injection check's own geometry (``workflows/elfin_independent_injection.py``).

The check rebuilds the body -> GEI rotation from the delivered files by TRIAD and turns
GEI signals into counts with it; these closed-form cases are what its numbers rest on.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import REPO_ROOT


@pytest.fixture(scope="module")
def wf():
    path = REPO_ROOT / "workflows" / "elfin_independent_injection.py"
    spec = importlib.util.spec_from_file_location("wf_independent_injection", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_triad_recovers_a_known_rotation(wf):
    """Truth: 50 random rotations; TRIAD from two body vectors and their images gives
    them back to 1e-12."""
    rng = np.random.default_rng(24)
    rot = Rotation.random(50, random_state=rng)
    a1, a2 = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    r = wf.triad(a1, a2, rot.apply(a1), rot.apply(a2))
    assert np.abs(r - rot.as_matrix()).max() < 1e-12


def test_body_axis_finds_a_tilted_spin_axis(wf):
    """Truth: a body frame whose spin axis is tilted 2 deg from body z; the regression
    of body z on the spin-axis field gives that axis back to 1e-6 rad."""
    rng = np.random.default_rng(7)
    x = np.linspace(-180.0, 180.0, 2000)
    axis = np.array([np.sin(np.radians(2.0)), 0.0, np.cos(np.radians(2.0))])
    e1 = np.cross(axis, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    phase = 2 * np.pi * x / 3.0
    b_axis = 5000.0 + 0.0 * x
    bb = (40000.0 * (np.cos(phase)[:, None] * e1 + np.sin(phase)[:, None] * e2)
          + b_axis[:, None] * axis + rng.normal(0.0, 1e-3, (x.size, 3)))
    got, rms = wf.body_axis(bb, b_axis, x, np.ones(x.size, bool), 60.0)
    assert np.abs(got - axis).max() < 1e-6 and rms < 0.01


def test_signals_have_their_stated_sizes(wf):
    """Truth: the signal definitions (200 nT / 40 s FWHM, 300 nT sheet rising 10-90 %
    in 20 s, 5 nT 2 Hz wave under a 10 s Hann window: its peak, a quarter period from
    the centre, within 1 %)."""
    x = np.arange(-200.0, 200.0, 0.01)
    g = wf.gaussian(x, 200.0, 40.0)
    above = x[g >= 100.0]
    assert g.max() == pytest.approx(200.0) and above[-1] - above[0] == pytest.approx(40.0, abs=0.02)
    s = wf.sheet(x, 300.0, 20.0)
    rise = x[(s >= 30.0) & (s <= 270.0)]
    assert rise[-1] - rise[0] == pytest.approx(20.0, abs=0.02) and s[-1] == pytest.approx(300.0)
    w = wf.hann_wave(x, 5.0, 2.0, 10.0)
    assert np.abs(w).max() == pytest.approx(5.0, rel=0.01) and not w[np.abs(x) > 5.0].any()


def test_config_carries_the_pipeline_settings(wf, tmp_path):
    """``--pipeline`` lines land in ``[spin.pipeline]`` of every run's configuration, as
    the chain reads it (an unknown key would be refused there); without them the
    configuration is the delivered pipeline's."""
    import tomllib

    from magcal.missions.elfin.settings import ElfinSettings

    fgs, state = tmp_path / "fgs.cdf", tmp_path / "state.cdf"
    plain, tuned = tmp_path / "plain.toml", tmp_path / "tuned.toml"
    wf.write_config(plain, fgs, state)
    wf.write_config(tuned, fgs, state, ["gain_drift_degree = 5", "pulses_b = false"])
    assert "pipeline" not in tomllib.loads(plain.read_text())["spin"]
    table = tomllib.loads(tuned.read_text())["spin"]["pipeline"]
    settings = ElfinSettings.from_mapping(table)
    assert (settings.gain_drift_degree, settings.pulses_b) == (5, False)
    assert tomllib.loads(tuned.read_text())["spin"]["units"] == "counts"
