"""Reference frames: sensor -> common sensor frame, spacecraft (OSRF) -> Hpen, GEO/GSE/GSM <-> Hpen.

The Hpen frame (GOES "EPN"): Hp along the local meridian, positive north; He earthward;
Hn eastward. (Hp, He, Hn) is a left-handed triad.
"""

from magcal.frames.hpen import geo_to_hpen, hpen_basis, hpen_to_geo, osrf_to_hpen

__all__ = ["geo_to_hpen", "hpen_basis", "hpen_to_geo", "osrf_to_hpen"]
