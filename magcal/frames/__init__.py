"""Reference frames: sensor -> common sensor frame, spacecraft (OSRF) -> Hpen, GEO/GSE/GSM <-> Hpen.

The Hpen frame (GOES "EPN" reordered): Hp along the local meridian, positive north; He
earthward; Hn eastward. (Hp, He, Hn) is a left-handed triad. GOES-R files store EPN in
the order (E, P, N) = (He, Hp, Hn); :func:`magcal.missions.goes.read_goes_mag` reorders it.
"""

from magcal.frames.geo import (
    FRAMES,
    GEOSTATIONARY_R_RE,
    convert_vectors,
    hpen_to,
    llr_from_geo,
    position_geo,
    rotation_matrices,
    to_hpen,
)
from magcal.frames.hpen import geo_to_hpen, hpen_basis, hpen_to_geo, osrf_to_hpen
from magcal.frames.sensor import (
    SensorFrames,
    check_rotation,
    from_common,
    rotation_from_euler,
    to_common,
)

__all__ = [
    "FRAMES", "GEOSTATIONARY_R_RE", "SensorFrames", "check_rotation", "convert_vectors",
    "from_common", "geo_to_hpen", "hpen_basis", "hpen_to", "hpen_to_geo", "llr_from_geo",
    "osrf_to_hpen", "position_geo", "rotation_from_euler", "rotation_matrices", "to_common",
    "to_hpen",
]
