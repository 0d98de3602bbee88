"""Quality control of instrument files, as ``magcal qc`` runs it: the same checks as
``magcal run`` applies to its inputs, on any supported files, for any verb's input.

The model check (``implausible_vs_model``) needs the model field and runs in the chain
only; everything else (spikes, saturated and stuck values, fills, time anomalies) runs
here on the readings as read.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.errors import InputError
from magcal.qc.flags import EXCLUDE
from magcal.qc.quality import QCResult, QCSettings, flag_samples


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

    def to_frame(self) -> pd.DataFrame:
        """``quality`` on the sample times (CONTRACTS 7.1 bits)."""
        return pd.DataFrame({"quality": self.result.flags.astype(np.uint16)},
                            index=self.times.rename("time"))

    def to_json(self) -> dict:
        return {"sensors": list(self.sensors), "cadence_s": self.cadence_s,
                "excluded_bits": int(EXCLUDE), **self.result.to_json(),
                "provenance": self.provenance}


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
    series = VectorSeries.from_frame(joined.sort_index(kind="stable"), source=files[0],
                                     on_duplicate="drop", mixed_cadence="allow")
    names = tuple(sensors) if sensors else tuple(s for s in series.sensors)
    for s in names:
        series[s]  # a clear error naming a sensor the files do not have
    s = settings or QCSettings()
    # the sensors named are taken as physically distinct (a pulse two of them see is a
    # field); the default of every sensor includes the same sensor in other frames
    result = flag_samples(series.times.as_unit("ns").asi8, {n: series[n] for n in names},
                          series.cadence_s, s, independent=tuple(sensors or ()))
    repairs = [dict(r, file=str(p)) for p, f in zip(files, frames)
               for r in f.attrs.get("repairs", []) if r.get("count", 1)]
    prov = {"files": [str(p) for p in files], "settings": s.__dict__.copy(),
            "repairs": repairs}
    return FileQuality(series.times, result, names, float(series.cadence_s), prov)
