"""The GK-2A-like layout: body, four SOSMAG sensors and the disturbers seen in 2019.

Body frame = spacecraft frame at nominal attitude (Magnes et al. 2020 §5.1): X east
(velocity), Y south, Z nadir; origin at the centre of the 2.9 x 2.4 x 4.6 m body, so
the walls are at |x| = 1.45, |y| = 1.2, |z| = 2.3 m. The 1 m boom sticks out east from
the +X wall; the outboard fluxgate ``fgmo`` is at its tip and the inboard ``fgmi``
0.8 m further in. ``amr1`` sits near the +X/+Y corner, ``amr2`` on the +X wall next
to the boom's launch lock.

The common frame is the outboard sensor frame, OSRF, with He = Bx, Hp = By, Hn = Bz:
``x_osrf = z_sc`` (nadir), ``y_osrf = -y_sc`` (north), ``z_osrf = x_sc`` (east).

Disturber sizes follow the papers (4 March 2019, |b| at the outboard sensor unless
stated): midnight disturbance ~34 nT (about 40x larger at AMR1, 5x at AMR2); its
triangular edge pulses ~2 nT; spikes ~5 nT (~14 nT at the inboard sensor); steps
~2.5 nT; broadband noise ~0.7 nT rms with a ~5 nT DC level at the inboard sensor;
the 6 s tone and the reaction wheel are sub-nT and come from sources far from the AMR
sensors. Moments are computed from those sizes at build time
(:func:`magcal.simulate.disturbers.moment_for_amplitude`).
"""

from __future__ import annotations

import numpy as np

from magcal.simulate.disturbers import Disturber, moment_for_amplitude
from magcal.simulate.profiles import (BroadbandNoiseProfile, DailyStepProfile,
                                      EdgePulseProfile, RotatingProfile, SpikeTrainProfile,
                                      ToggleStepProfile, ToneProfile)
from magcal.simulate.sensors import Sensor

#: Rows: OSRF axes in body (spacecraft) coordinates; ``b_osrf = M @ b_body``.
GK2A_BODY_TO_OSRF = ((0.0, 0.0, 1.0), (0.0, -1.0, 0.0), (1.0, 0.0, 0.0))
#: Spacecraft body size (x, y, z) in metres.
GK2A_BODY_SIZE_M = (2.9, 2.4, 4.6)

FGMO_POS = (2.55, -0.8, -1.6)
FGMI_POS = (1.75, -0.8, -1.6)
AMR1_POS = (1.25, 1.0, -0.6)
AMR2_POS = (1.30, -0.5, -1.2)

FG_NOISE_NT = 0.03
AMR_NOISE_NT = 20 * FG_NOISE_NT


def gk2a_sensors() -> tuple[Sensor, ...]:
    """The four SOSMAG sensors (fluxgate noise 0.03 nT rms, AMR 20x more)."""
    return (
        Sensor("fgmo", FGMO_POS, noise_nT=FG_NOISE_NT, offset_nT=(4.0, -3.0, 6.0),
               misalignment_deg=(0.3, -0.2, 0.1), on_boom=True,
               temp_coeff_nT_per_K=(0.012, -0.008, 0.005), soo_amplitude_nT=2.0,
               soo_period_s=150.0),
        Sensor("fgmi", FGMI_POS, noise_nT=FG_NOISE_NT, offset_nT=(-5.0, 7.0, 2.0),
               misalignment_deg=(0.2, 0.4, -0.3), on_boom=True,
               temp_coeff_nT_per_K=(-0.006, 0.010, 0.008), soo_amplitude_nT=1.5,
               soo_period_s=170.0),
        Sensor("amr1", AMR1_POS, noise_nT=AMR_NOISE_NT, offset_nT=(40.0, -25.0, 60.0),
               misalignment_deg=(1.0, -0.5, 0.8)),
        Sensor("amr2", AMR2_POS, noise_nT=AMR_NOISE_NT, offset_nT=(-30.0, 45.0, -20.0),
               misalignment_deg=(-0.7, 0.6, 0.5)),
    )


def _dipole(name, position, direction, amplitude_nT, profile, at=FGMO_POS, **kw):
    kind = kw.pop("kind", "dipole")
    moment = moment_for_amplitude("dipole" if kind == "rotating" else kind, position,
                                  direction, at, amplitude_nT, kw.get("separation_m"))
    return Disturber(name, tuple(position), tuple(moment.round(9)), profile, kind=kind, **kw)


def gk2a_disturbers() -> tuple[Disturber, ...]:
    """The seven disturbers of the GK-2A-like layout (see the module docstring)."""
    md = DailyStepProfile()
    cluster = np.array([-0.2, -0.5, -1.0])  # spikes, noise and steps share one unit
    return (
        _dipole("midnight", (1.2, 0.8, -1.3), (0.16, -0.17, 0.97), 34.0, md),
        _dipole("md_edge", (-0.6, -1.0, -2.0), (0.6, -0.2, 0.7), 2.0,
                EdgePulseProfile(step=md)),
        _dipole("spikes", cluster, (0.8, 0.5, 0.3), 4.9, SpikeTrainProfile()),
        _dipole("hf_noise", cluster + (0.1, 0.05, 0.0), (0.61, 0.77, 0.19), 0.7,
                BroadbandNoiseProfile(), at=FGMI_POS),
        _dipole("steps", cluster + (0.0, 0.1, 0.1), (0.29, -0.68, 0.67), 2.5,
                ToggleStepProfile()),
        _dipole("tone_6s", (-1.0, -0.9, -2.1), (0.0, 0.3, 1.0), 0.05, ToneProfile(6.0),
                kind="quadrupole", separation_m=(0.1, 0.0, 0.0)),
        _dipole("reaction_wheel", (-0.9, 0.0, 1.0), (1.0, 0.0, 0.0), 0.1, RotatingProfile(),
                kind="rotating", rotation_axis=(0.0, 1.0, 1.0)),
    )
