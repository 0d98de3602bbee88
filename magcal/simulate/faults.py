"""Faults of real archives, applied to a clean simulated archive.

:func:`inject_faults` takes the folder :func:`magcal.simulate.archive.write_archive_files`
wrote (``raw/day_YYYYMMDD.csv``, ``raw/kp.csv``, ...) and changes it as instrument
archives go wrong: missing days, a Kp file with a hole, spikes, saturation, stuck
values, fills, duplicated and overlapping files, files whose names sort out of time
order, a day at another cadence or in another format, a truncated last line, a corrupt
gzip file, a file with another sensor set, CRLF line ends, ``+00:00`` stamps and
off-grid time stamps. Each fault returns an :class:`InjectedFault` saying which days and
files it touched, which samples it spoiled (so a quality check can be scored against
them) and what a run must do about it (fail that partition, warn, or nothing).

Only the files a fault names are rewritten: every other file keeps its bytes, so a run
on the faulty archive can be compared day by day with the clean run.

Examples
--------
>>> import tempfile
>>> from magcal.simulate.archive import ArchiveConfig, simulate_archive, write_archive_files
>>> tmp = Path(tempfile.mkdtemp())
>>> res = simulate_archive(ArchiveConfig(n_days=4, cadence_s=600),
...                        rng=np.random.default_rng(1))
>>> _ = write_archive_files(res, tmp / "raw")
>>> done = inject_faults(tmp / "raw", [Fault("spikes", day=1)], rng=np.random.default_rng(2))
>>> done[0].kind, done[0].expect, len(done[0].bad_samples["2019-11-02"]) > 0
('spikes', 'warning', True)
"""

from __future__ import annotations

import gzip
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from magcal.errors import InputError

#: Fault kinds, and what a run must do about each: ``failed`` (the partition of the
#: file fails with its reason), ``warning`` (the run goes on and names it) or ``none``
#: (a benign difference: the products of the other days are unchanged).
FAULT_KINDS = {
    "missing_days": "failed",      # n consecutive daily files absent
    "kp_hole": "warning",          # the Kp file lacks n days
    "spikes": "warning",           # one component at 1e6 nT every 97th sample
    "saturation": "warning",       # all components of a sensor at 65535 for 400 samples
    "stuck": "warning",            # one sensor repeats one reading for 200 samples
    "fill": "warning",             # a block of -1e31 fill values and NaN
    "duplicate_file": "warning",   # a second copy of a day under another name
    "overlap_file": "warning",     # a file spanning the end of one day and the next
    "renamed": "none",             # a day's file name sorts out of time order
    "cadence": "none",             # a day at twice the cadence
    "other_format": "none",        # a day as ISTP CDF among CSV files
    "truncated": "warning",        # the last line cut in the middle
    "corrupt_gzip": "failed",      # a gzip file with damaged bytes
    "other_sensors": "failed",     # a day whose file has another sensor set
    "crlf": "none",                # CRLF line ends and +00:00 stamps
    "time_jitter": "warning",      # a block of stamps off the cadence grid
}

_DAY = np.timedelta64(1, "D")


@dataclass(frozen=True)
class Fault:
    """One fault to inject.

    Attributes
    ----------
    kind : str
        One of :data:`FAULT_KINDS`.
    day : int
        Index of the (first) daily file it touches, in time order (0 = first day).
    n_days : int
        Days it spans (``missing_days``, ``kp_hole``).
    sensor : str
        Sensor it spoils (``spikes``, ``saturation``, ``stuck``, ``fill``).
    """

    kind: str
    day: int = 0
    n_days: int = 1
    sensor: str = "fgmo"

    def __post_init__(self):
        if self.kind not in FAULT_KINDS:
            raise InputError(f"unknown fault {self.kind!r}; known: {', '.join(FAULT_KINDS)}")


@dataclass(frozen=True)
class InjectedFault:
    """What :func:`inject_faults` did for one :class:`Fault`.

    Attributes
    ----------
    kind : str
    days : tuple of str
        UTC days (``YYYY-MM-DD``) whose data or files it touched.
    files : tuple of str
        File names (in the folder) it created, changed or removed.
    expect : str
        ``failed``, ``warning`` or ``none`` (:data:`FAULT_KINDS`).
    bad_samples : dict
        ``day -> sorted sample indices`` (rows of that day's original file) whose values
        it spoiled: what a quality check must flag.
    """

    kind: str
    days: tuple
    files: tuple
    expect: str
    bad_samples: dict = field(default_factory=dict)


def day_files(folder: Path) -> list[Path]:
    """The clean archive's daily files in time order (``day_YYYYMMDD.csv``)."""
    return sorted(Path(folder).glob("day_????????.csv"))


def _day_of(path: Path) -> str:
    s = path.stem.split("_")[-1]
    return f"{s[:4]}-{s[4:6]}-{s[6:8]}"


def _read(path: Path) -> pd.DataFrame:
    return pd.read_csv(path, dtype={"time": str})


def _write(frame: pd.DataFrame, path: Path, *, line_end: str = "\n") -> None:
    frame.to_csv(path, index=False, float_format="%.3f", lineterminator=line_end)


def _cols(frame: pd.DataFrame, sensor: str) -> list[str]:
    cols = [f"{sensor}_{c}" for c in "xyz"]
    if not all(c in frame.columns for c in cols):
        raise InputError(f"the archive has no sensor {sensor!r}")
    return cols


def inject_faults(folder: str | Path, faults, *, rng: np.random.Generator) -> list[InjectedFault]:
    """Apply ``faults`` to the archive in ``folder`` (changed in place).

    Parameters
    ----------
    folder : path
        The ``raw`` folder of :func:`~magcal.simulate.archive.write_archive_files`.
    faults : sequence of Fault
        Applied in order; two faults on the same day are allowed but their
        ``bad_samples`` then describe each alone.
    rng : numpy.random.Generator
        Chooses where in a day a block fault starts.

    Returns
    -------
    list of InjectedFault
    """
    if not isinstance(rng, np.random.Generator):
        raise InputError("rng must be a numpy.random.Generator")
    folder = Path(folder)
    days = day_files(folder)
    if not days:
        raise InputError("no day_YYYYMMDD.csv files", file=folder)
    out = []
    for fault in faults:
        if not 0 <= fault.day < len(days):
            raise InputError(f"fault {fault.kind}: day {fault.day} outside the "
                             f"archive's {len(days)} days")
        out.append(_APPLY[fault.kind](folder, days, fault, rng))
    return out


def _done(fault: Fault, days, files, bad=None) -> InjectedFault:
    return InjectedFault(fault.kind, tuple(days), tuple(str(f) for f in files),
                         FAULT_KINDS[fault.kind], dict(bad or {}))


def _missing_days(folder, days, fault, rng):
    gone = days[fault.day:fault.day + fault.n_days]
    for p in gone:
        p.unlink()
    return _done(fault, [_day_of(p) for p in gone], [p.name for p in gone])


def _kp_hole(folder, days, fault, rng):
    kp_path = folder / "kp.csv"
    kp = _read(kp_path)
    t = pd.to_datetime(kp["time"]).to_numpy()
    start = np.datetime64(_day_of(days[fault.day]))
    keep = (t < start) | (t >= start + fault.n_days * _DAY)
    kp[keep].to_csv(kp_path, index=False)
    hole = [str((start + k * _DAY).astype("datetime64[D]")) for k in range(fault.n_days)]
    return _done(fault, hole, [kp_path.name])


def _spoil(fault, days, rng, change):
    path = days[fault.day]
    frame = _read(path)
    rows = change(frame, _cols(frame, fault.sensor), rng)
    _write(frame, path)
    return _done(fault, [_day_of(path)], [path.name], {_day_of(path): sorted(rows)})


def _spikes(folder, days, fault, rng):
    def change(frame, cols, rng):
        rows = np.arange(48, len(frame), 97)
        frame.loc[rows, cols[0]] = 1e6
        return rows.tolist()
    return _spoil(fault, days, rng, change)


def _block(frame, n, rng):
    n = min(n, len(frame) // 2)
    start = int(rng.integers(1, len(frame) - n))
    return np.arange(start, start + n)


def _saturation(folder, days, fault, rng):
    def change(frame, cols, rng):
        rows = _block(frame, 400, rng)
        frame.loc[rows, cols] = 65535.0
        return rows.tolist()
    return _spoil(fault, days, rng, change)


def _stuck(folder, days, fault, rng):
    def change(frame, cols, rng):
        rows = _block(frame, 200, rng)
        frame.loc[rows, cols] = frame.loc[rows[0] - 1, cols].to_numpy(dtype=float)
        return rows.tolist()
    return _spoil(fault, days, rng, change)


def _fill(folder, days, fault, rng):
    def change(frame, cols, rng):
        rows = _block(frame, 120, rng)
        frame.loc[rows[:60], cols] = -1e31
        frame.loc[rows[60:], cols] = np.nan
        return rows.tolist()
    return _spoil(fault, days, rng, change)


def _duplicate_file(folder, days, fault, rng):
    path = days[fault.day]
    copy = folder / f"{path.stem}_copy.csv"
    shutil.copyfile(path, copy)
    return _done(fault, [_day_of(path)], [copy.name])


def _overlap_file(folder, days, fault, rng):
    first = days[fault.day]
    second = days[fault.day + 1] if fault.day + 1 < len(days) else None
    a = _read(first)
    parts = [a.iloc[len(a) * 3 // 4:]]
    if second is not None:
        b = _read(second)
        parts.append(b.iloc[:len(b) // 4])
    path = folder / f"{first.stem}_overlap.csv"
    pd.concat(parts).to_csv(path, index=False)  # the values as read: same text
    touched = [_day_of(first)] + ([_day_of(second)] if second is not None else [])
    return _done(fault, touched, [path.name])


def _renamed(folder, days, fault, rng):
    path = days[fault.day]
    new = folder / f"day_0_{path.stem.split('_')[-1]}.csv"  # sorts before every day
    path.rename(new)
    return _done(fault, [_day_of(path)], [new.name])


def _cadence(folder, days, fault, rng):
    path = days[fault.day]
    frame = _read(path)
    frame.iloc[::2].to_csv(path, index=False)
    return _done(fault, [_day_of(path)], [path.name])


def _other_format(folder, days, fault, rng):
    from magcal.io.formats import read_any, write_any

    path = days[fault.day]
    frame = read_any(path)
    new = path.with_suffix(".cdf")
    write_any(new, frame, "cdf")
    path.unlink()
    return _done(fault, [_day_of(path)], [new.name])


def _truncated(folder, days, fault, rng):
    path = days[fault.day]
    raw = path.read_bytes().rstrip(b"\n")
    last = raw.rfind(b"\n")
    path.write_bytes(raw[:last + 1 + (len(raw) - last) // 2])  # half the last line
    n = raw.count(b"\n") - 1  # rows are counted from 0 after the header
    return _done(fault, [_day_of(path)], [path.name], {_day_of(path): [n]})


def _corrupt_gzip(folder, days, fault, rng):
    path = days[fault.day]
    data = bytearray(gzip.compress(path.read_bytes()))
    mid = len(data) // 2
    data[mid:mid + 64] = bytes(rng.integers(0, 256, 64, dtype=np.uint8))
    new = path.with_suffix(".csv.gz")
    new.write_bytes(bytes(data))
    path.unlink()
    return _done(fault, [_day_of(path)], [new.name])


def _other_sensors(folder, days, fault, rng):
    path = days[fault.day]
    frame = _read(path)
    frame.columns = [c.replace("fgmi_", "fgmx_") for c in frame.columns]
    _write(frame, path)
    return _done(fault, [_day_of(path)], [path.name])


def _crlf(folder, days, fault, rng):
    path = days[fault.day]
    frame = _read(path)
    frame["time"] = frame["time"].str.replace("Z", "", regex=False) + "+00:00"
    _write(frame, path, line_end="\r\n")
    return _done(fault, [_day_of(path)], [path.name])


def _time_jitter(folder, days, fault, rng):
    path = days[fault.day]
    frame = _read(path)
    t = pd.to_datetime(frame["time"])
    cadence = (t.iloc[1] - t.iloc[0])
    rows = _block(frame, 20, rng)
    shifted = t.iloc[rows] + cadence * 0.4
    frame.loc[rows, "time"] = shifted.dt.strftime("%Y-%m-%dT%H:%M:%S.%f").to_numpy()
    _write(frame, path)
    return _done(fault, [_day_of(path)], [path.name], {_day_of(path): rows.tolist()})


_APPLY = {
    "missing_days": _missing_days, "kp_hole": _kp_hole, "spikes": _spikes,
    "saturation": _saturation, "stuck": _stuck, "fill": _fill,
    "duplicate_file": _duplicate_file, "overlap_file": _overlap_file, "renamed": _renamed,
    "cadence": _cadence, "other_format": _other_format, "truncated": _truncated,
    "corrupt_gzip": _corrupt_gzip, "other_sensors": _other_sensors, "crlf": _crlf,
    "time_jitter": _time_jitter,
}
