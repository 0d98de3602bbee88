"""Quality control of instrument files, as ``magcal qc`` runs it: the same checks as
``magcal run`` applies to its inputs, on any supported files, for any verb's input.

The model check (``implausible_vs_model``) needs the model field and runs in the chain
only; everything else (spikes, saturated and stuck values, fills, time anomalies) runs
here on the readings as read.

Every field column is checked, not only complete ``<sensor>_x,_y,_z`` sets (the other
verbs' layout): a sensor with some of its components (``fgmo_x,fgmo_z``) is checked
on those, per component, and named as incomplete; components with a unit suffix
(``fgmo_x_uT``) are checked under their sensor, their unit named. Columns that are no
field component (``phase``, ``b_total``...) are listed as not checked.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.errors import InputError
from magcal.qc.flags import EXCLUDE
from magcal.qc.quality import QCResult, QCSettings, flag_samples
from magcal.timeseries import COMPONENT_SETS

#: A field component outside a complete set: ``[<sensor>_]<component>[_<unit>]``
#: (``fgmo_x``, ``fgmo_x_uT``, ``Hp``; the r,t,n components only after a sensor).
_FIELD_COLUMN = re.compile(
    r"^(?:(?P<sensor>\S+?)_(?P<rtn>[rtn])|(?:(?P<sensor2>\S+?)_)?"
    r"(?P<comp>x|y|z|X|Y|Z|Hp|He|Hn|b1|b2|b3))"
    r"(?:_(?P<unit>(?i:nT|uT|µT|mT|pT|T|G|mG|gauss|nanotesla|tesla)))?$")
_ORDER = {c: k for comps in COMPONENT_SETS for k, c in enumerate(comps)}


@dataclass(frozen=True)
class FieldColumns:
    """The field columns of a flat frame, grouped into sensors.

    Attributes
    ----------
    columns : dict
        ``sensor -> [(column, component), ...]`` in component order.
    missing : dict
        ``sensor -> [column, ...]``: the components of its set it lacks (incomplete).
    units : dict
        ``sensor -> unit`` of the sensors whose columns carry a unit suffix.
    not_checked : list
        The other (non-time) columns.

    Examples
    --------
    >>> fc = FieldColumns.of(["fgmo_x", "fgmo_z", "fgmi_x", "fgmi_y", "fgmi_z",
    ...                       "amr_x_uT", "amr_y_uT", "amr_z_uT", "phase"])
    >>> fc.missing, fc.units, fc.not_checked
    ({'fgmo': ['fgmo_y']}, {'amr': 'uT'}, ['phase'])
    >>> [c for c, _ in fc.columns["amr"]]
    ['amr_x_uT', 'amr_y_uT', 'amr_z_uT']
    """

    columns: dict
    missing: dict
    units: dict
    not_checked: list

    @classmethod
    def of(cls, names) -> "FieldColumns":
        from magcal.timeseries import _split_flat_columns

        names = [str(c) for c in names]
        pairs, rest = _split_flat_columns(names)
        columns: dict = {}
        for sensor, comp in pairs:  # the complete sets the other verbs read
            columns.setdefault(sensor, []).append((f"{sensor}_{comp}" if sensor else comp,
                                                   comp))
        groups: dict = {}
        not_checked = []
        for name in rest:
            m = _FIELD_COLUMN.match(name)
            if not m:
                not_checked.append(name)
                continue
            sensor = m["sensor"] or m["sensor2"] or ""
            groups.setdefault((sensor, m["unit"]), []).append((name, m["rtn"] or m["comp"]))
        missing, units = {}, {}
        for (sensor, unit), cols in groups.items():
            name = sensor
            if name in columns:  # fgmo_x,_y,_z and fgmo_x_uT: the suffixed set apart
                name = f"{sensor}_{(unit or 'partial').lower()}".lstrip("_")
            cols = sorted(cols, key=lambda c: _ORDER.get(c[1], 0))
            columns[name] = cols
            if unit:
                units[name] = unit
            comps = {c for _, c in cols}
            full = max(COMPONENT_SETS, key=lambda s: len(comps & set(s)))
            lacking = [c for c in full if c not in comps]
            if lacking:
                prefix = f"{sensor}_" if sensor else ""
                suffix = f"_{unit}" if unit else ""
                missing[name] = [f"{prefix}{c}{suffix}" for c in lacking]
        at = {c: k for k, c in enumerate(names)}  # sensors in the order of the file
        columns = dict(sorted(columns.items(), key=lambda kv: at[kv[1][0][0]]))
        return cls(columns, missing, units, not_checked)


@dataclass(frozen=True)
class FileQuality:
    """The quality flag of every sample of a set of files.

    Attributes
    ----------
    times : pandas.DatetimeIndex
        Sample times (UTC), increasing, duplicates of overlapping files dropped.
    result : QCResult
        Flags (bitwise OR over ``sensors``) and counts per sensor.
    sensors : tuple of str
        Sensors checked.
    cadence_s : float
        The record's nominal cadence (s).
    provenance : dict
        Files, settings and reader repairs.
    """

    times: pd.DatetimeIndex
    result: QCResult
    sensors: tuple
    cadence_s: float
    provenance: dict = field(default_factory=dict)
    layout: FieldColumns | None = None

    def to_frame(self) -> pd.DataFrame:
        """``quality`` on the sample times (CONTRACTS 7.1 bits)."""
        return pd.DataFrame({"quality": self.result.flags.astype(np.uint16)},
                            index=self.times.rename("time"))

    def to_json(self) -> dict:
        out = {"sensors": list(self.sensors), "cadence_s": self.cadence_s,
               "excluded_bits": int(EXCLUDE), **self.result.to_json(),
               "provenance": self.provenance}
        lay = self.layout
        if lay is not None:
            out["checked"] = {s: [c for c, _ in lay.columns[s]] for s in self.sensors}
            out["incomplete"] = {s: lay.missing[s] for s in self.sensors if s in lay.missing}
            out["units"] = {s: lay.units[s] for s in self.sensors if s in lay.units}
            out["columns_not_checked"] = list(lay.not_checked)
        from magcal.qc.checks import time_gaps

        gaps = time_gaps(self.times.as_unit("ns").asi8, self.cadence_s)
        out["time_gaps"] = {"count": len(gaps), "longest_s": max((g for _, g in gaps),
                                                                  default=0.0),
                            "first": [[self.times[i - 1].isoformat(), self.times[i].isoformat(),
                                       g] for i, g in gaps[:20]]}
        return out

    def warnings(self) -> list:
        """One line per sensor checked on some of its components or in another unit."""
        lay, out = self.layout, []
        if lay is None:
            return out
        for s in self.sensors:
            cols = ", ".join(c for c, _ in lay.columns[s])
            if s in lay.missing:
                out.append(f"sensor {s!r} has no column {', '.join(lay.missing[s])}: "
                           f"checked on {cols}, per component")
            if s in lay.units:
                out.append(f"sensor {s!r} is in {lay.units[s]} (columns {cols}), not nT: "
                           "checked as read")
        return out


def check_files(paths, settings: QCSettings | None = None, sensors=None,
                input_format: str = "auto") -> FileQuality:
    """Read ``paths`` (any supported format, joined in time order) and flag every sample.

    Parameters
    ----------
    paths : sequence of path-like
    settings : QCSettings, optional
        Thresholds (CHAIN.toml ``[qc]``); the documented defaults when omitted.
    sensors : sequence of str, optional
        Sensors to check (default: every sensor of the files). Named sensors are taken
        as physically distinct: a spike two of them see at once is a field, not flagged
        (the default, every sensor, includes the same sensor in other frames).
    input_format : str
        ``auto`` (detected by content) or one of :data:`magcal.io.formats.FORMATS`.

    Returns
    -------
    FileQuality

    Examples
    --------
    >>> import tempfile, os
    >>> t = pd.date_range("2020-01-01", periods=600, freq="30s", tz="UTC")
    >>> rng = np.random.default_rng(1)
    >>> b = 100 + rng.normal(0, 0.1, (600, 3)).cumsum(axis=0)
    >>> b[300, 0] = 1e6
    >>> frame = pd.DataFrame(b, index=t, columns=["fgm_x", "fgm_y", "fgm_z"])
    >>> path = os.path.join(tempfile.mkdtemp(), "day.csv")
    >>> frame.rename_axis("time").to_csv(path, date_format="%Y-%m-%dT%H:%M:%SZ")
    >>> check_files([path]).result.counts()
    {'spike': 1}
    """
    from magcal.io.formats import in_time_order, read_any
    from magcal.timeseries import VectorSeries

    files = in_time_order([Path(p) for p in paths])
    if not files:
        raise InputError("no input files")
    frames = [read_any(p, input_format) for p in files]
    joined = pd.concat(frames, axis=0, sort=False) if len(frames) > 1 else frames[0]
    s = settings or QCSettings()
    layout = FieldColumns.of(joined.columns)
    if layout.columns:
        # every field column, complete sets or not, as (sensor, component) columns
        cols = [(sensor, col, comp) for sensor, cc in layout.columns.items()
                for col, comp in cc]
        joined = joined[[c for _, c, _ in cols]].set_axis(
            pd.MultiIndex.from_tuples([(sn, comp) for sn, _, comp in cols],
                                      names=["sensor", "component"]), axis=1)
    series = VectorSeries.from_frame(joined.sort_index(kind="stable"), source=files[0],
                                     on_duplicate="drop", mixed_cadence="allow")
    names = tuple(sensors) if sensors else tuple(s for s in series.sensors)
    for n in names:
        series[n]  # a clear error naming a sensor the files do not have
        if s.range_nT is not None and n in layout.units \
                and layout.units[n].lower() != "nt":
            raise InputError(f"sensor {n!r} is in {layout.units[n]}, the declared range "
                             f"(--range-nt / [qc] range_nT) in nT", file=files[0],
                             column=layout.columns[n][0][0])
    # the sensors named are taken as physically distinct (a pulse two of them see is a
    # field); the default of every sensor includes the same sensor in other frames
    result = flag_samples(series.times.as_unit("ns").asi8, {n: series[n] for n in names},
                          series.cadence_s, s, independent=tuple(sensors or ()))
    repairs = [dict(r, file=str(p)) for p, f in zip(files, frames)
               for r in f.attrs.get("repairs", []) if r.get("count", 1)]
    prov = {"files": [str(p) for p in files], "settings": s.__dict__.copy(),
            "repairs": repairs}
    return FileQuality(series.times, result, names, float(series.cadence_s), prov, layout)
