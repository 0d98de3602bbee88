"""What the columns of magcal's products mean: units, descriptions, CF standard names and
the quality flag bits, in one place for every product format.

The CSV, netCDF and CDF writers of :mod:`magcal.io.products` describe a column by
:func:`describe`; the quality flag's bits and names are those of
:data:`magcal.qc.flags.FLAG_NAMES` (CONTRACTS §7.1), the one table of them: a new check
adds its bit there and every format writes it.

Examples
--------
>>> describe("Hp")["units"], describe("quality")["flag_masks"][:3]
('nT', [1, 2, 4])
>>> describe("quality")["flag_meanings"].split()[0]
'spike'
>>> describe("fgmo_x")["units"]
'nT'
"""

from __future__ import annotations

import re

_HPEN = {"Hp": "along the local meridian, positive north",
         "He": "earthward", "Hn": "eastward"}

#: Column -> attributes (``units``, ``long_name``, optional ``standard_name``).
_KNOWN = {
    **{c: {"units": "nT", "long_name": f"magnetic field {c} component ({d})"}
       for c, d in _HPEN.items()},
    **{f"{c}_std": {"units": "nT", "long_name": f"standard deviation of the selected "
                    f"samples' {c} minus model"} for c in _HPEN},
    **{f"{c}_mad": {"units": "nT", "long_name": f"scaled MAD of the selected samples' {c} "
                    f"minus model"} for c in _HPEN},
    **{f"{c}_se": {"units": "nT", "long_name": f"1-sigma standard error of the window's {c} "
                   f"offset (correlation accounted for)"} for c in _HPEN},
    **{f"{c}_dof": {"units": "1", "long_name": f"degrees of freedom of {c}_se: the 95 % "
                    f"interval is the offset +- t(0.975, dof) {c}_se"} for c in _HPEN},
    "offset_flag": {"units": "1", "long_name": "how the offset of this sample was obtained"},
    "n_used": {"units": "1", "long_name": "samples used in the window"},
    "n_available": {"units": "1", "long_name": "samples available in the window"},
    "fraction_used": {"units": "1", "long_name": "fraction of the available samples used"},
    "reason": {"units": "1", "long_name": "why the window has no offset, or a caution"},
    "days_covered": {"units": "day", "long_name": "days of the window holding used samples"},
    "lt_hours_covered": {"units": "h", "long_name": "local-time hours (of 24) holding used "
                         "samples"},
    "center": {"long_name": "window centre", "standard_name": "time"},
    "start": {"long_name": "window start (inclusive)"},
    "end": {"long_name": "window end (exclusive)"},
    "time": {"long_name": "time of the sample, UTC", "standard_name": "time"},
    "lon_deg": {"units": "degrees_east", "long_name": "geographic longitude",
                "standard_name": "longitude"},
    "lat_deg": {"units": "degrees_north", "long_name": "geographic latitude",
                "standard_name": "latitude"},
    "r_re": {"units": "Earth radii", "long_name": "geocentric distance (6371.2 km radii)"},
    "kp": {"units": "1", "long_name": "Kp index"},
}


def quality_attributes() -> dict:
    """The ``quality`` column's description as a CF flag variable: ``flag_masks`` and
    ``flag_meanings`` are the bits and names of :data:`magcal.qc.flags.FLAG_NAMES`."""
    from magcal.qc.flags import FLAG_NAMES

    return {"units": "1", "standard_name": "quality_flag",
            "long_name": "sample quality bit flags (0 = good): " + "; ".join(
                f"{m} {n.replace('_', ' ')}" for m, n in FLAG_NAMES.items()),
            "flag_masks": list(FLAG_NAMES),
            "flag_meanings": " ".join(FLAG_NAMES.values())}


def describe(column: str) -> dict:
    """``units``, ``long_name`` and (where CF has one) ``standard_name`` of a column.

    Unknown columns get ``units = "1"`` and their name as description; sensor vectors
    (``<sensor>_x``) and ``b1..b3`` are nT.
    """
    if column == "quality":
        return quality_attributes()
    if column == "offset_flag":
        from magcal.offsets.apply import FLAG_MEANING

        return {**_KNOWN[column], "flag_values": sorted(FLAG_MEANING),
                "flag_meanings": " ".join(_word(FLAG_MEANING[k]) for k in sorted(FLAG_MEANING))}
    if column in _KNOWN:
        return dict(_KNOWN[column])
    m = re.fullmatch(r"([a-z0-9_]+)_([xyz]|Hp|He|Hn)", column)
    if m:
        return {"units": "nT", "long_name": f"magnetic field of {m.group(1)}, "
                f"{m.group(2)} component"}
    if re.fullmatch(r"b[123]", column):
        return {"units": "nT", "long_name": f"sensor reading {column}"}
    return {"units": "1", "long_name": column}


def _word(text: str) -> str:
    """A description as one CF ``flag_meanings`` word (its part before a colon)."""
    return re.sub(r"\W+", "_", text.split(":")[0].strip()).strip("_")
