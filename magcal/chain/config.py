"""The chain configuration (``CHAIN.toml``): parsed with :mod:`tomllib`, checked key by key.

Every section is a frozen dataclass; an unknown section or key, a wrong type or a
missing required key is an :class:`~magcal.errors.InputError` naming the file, the
section and the key. Paths are relative to the TOML file. The schema, with defaults,
is documented in the README ("Chain configuration") and in :data:`SCHEMA`.
"""

from __future__ import annotations

import glob
import math
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from magcal.errors import InputError
from magcal.qc.quality import QCSettings

_MISSING = object()

#: section -> key -> (type(s), default; _MISSING = required). Documented in the README.
SCHEMA: dict[str, dict[str, tuple]] = {
    "input": {"files": (list, _MISSING), "format": (str, "auto"), "target": (str, None),
              "sensors": (list, None), "frame": (str, "hpen"), "simulate": (dict, None),
              "spacecraft": (str, None)},
    "frames": {"to_common": (dict, {}), "reference": (str, None),
               "to_hpen": ((str, list), None), "hpen_reference": (str, ""),
               "fit_offset": ((str, bool), "auto")},
    "position": {"longitude_deg": ((int, float), None), "latitude_deg": ((int, float), 0.0),
                 "r_re": ((int, float), 6.6), "columns": (bool, False)},
    "kp": {"file": (str, None)},
    "model": {"name": (str, "T89"), "drivers": (str, None), "cache_dir": (str, None),
              "cadence_s": ((int, float), 60.0), "jobs": (int, None)},
    "picog": {"plan": (str, "auto"), "on_worse": (str, "raw"),
              "fit_days": ((int, float), 3.0), "fit_max_samples": (int, 1_000_000)},
    "offsets": {"kp_max": ((int, float), 1.0), "window_days": ((int, float), 28.0),
                "step_days": ((int, float), 7.0), "method": (str, "median"),
                "min_used": (int, 720), "cadence_s": ((int, float), 60.0),
                "split_at_level_changes": (bool, False)},
    "alignment": {"reference": (str, "model"), "mcmc": (bool, False), "seed": (int, 0),
                  "lt_harmonics": ((str, int), "auto"), "window_days": ((str, int, float), "auto"),
                  "kp_max": ((int, float), 1.0), "enabled": (bool, True),
                  "cadence_s": ((int, float), 60.0), "noise_model": (str, "ou+ou+white")},
    "discover": {"enabled": (bool, True), "max_effects": (int, 8), "covariates": (str, None)},
    "report": {"enabled": (bool, True), "pdf": (bool, False)},
    "truth": {"file": (str, None)},
    "output": {"format": (str, "auto")},
    "qc": QCSettings.schema(),  # sample quality control (magcal.qc; README "[qc]")
    "spin": {"spin_period_s": ((int, float), None), "flipper": (bool, True),
             "units": (str, "nT"), "reference": (str, None), "state": (str, None),
             "pipeline": (dict, {}), "disturbed": (list, [])},
}
#: Sections a spinning-spacecraft chain may hold.
SPIN_SECTIONS = ("input", "spin", "report", "truth")


@dataclass(frozen=True)
class ChainConfig:
    """A parsed, checked ``CHAIN.toml``.

    Attributes
    ----------
    path : pathlib.Path
        The TOML file (relative paths in it are relative to its folder).
    sections : dict
        ``section -> {key: value}`` with defaults filled in.
    kind : {"geostationary", "spin"}
        ``spin`` when the file has a ``[spin]`` section.
    outdir : pathlib.Path, optional
        The run's output folder: a path starting with ``{outdir}`` is resolved in it
        (the input that ``[input] simulate`` writes there).
    """

    path: Path
    sections: dict = field(default_factory=dict)
    kind: str = "geostationary"
    outdir: Path | None = None

    def __getitem__(self, section: str) -> dict:
        return self.sections[section]

    def resolve(self, relative: str | None) -> Path | None:
        """A path from the file: relative to the TOML file's folder, or to the output
        folder when it starts with ``{outdir}``."""
        if relative is None:
            return None
        if relative.startswith("{outdir}"):
            if self.outdir is None:
                raise InputError(f"{relative!r}: {{outdir}} is only known during a run",
                                 file=self.path)
            return self.outdir / relative[len("{outdir}"):].lstrip("/\\")
        p = Path(relative).expanduser()
        return p if p.is_absolute() else (self.path.parent / p)

    def input_files(self) -> list[Path]:
        """The input files: every glob of ``[input] files`` expanded, sorted, unique."""
        found: list[Path] = []
        for pattern in self["input"]["files"]:
            full = self.resolve(pattern)
            hits = sorted(Path(h) for h in glob.glob(str(full)))
            if not hits:
                raise InputError(f"[input] files: {pattern!r} matches no file", file=self.path)
            found += [h for h in hits if h.is_file() and h not in found]
        return found

    def check_paths(self) -> None:
        """Every file the configuration names must exist and hold something (after
        ``[input] simulate`` wrote its ``{outdir}`` files).

        A missing Kp, covariate, truth, plan, reference or driver file is a bad
        configuration (exit status 2, naming the key), not a stage that fails late
        (exit 3) after the partitions ran: a typo in ``[discover] covariates`` used to
        cost the whole run and then fail only discovery.

        Raises
        ------
        InputError
            Naming the TOML file, the key (``column``) and the path.
        """
        keys = [("kp", "file"), ("model", "drivers"), ("discover", "covariates"),
                ("truth", "file"), ("picog", "plan"), ("alignment", "reference")]
        skip = {("picog", "plan"): ("auto", "none"), ("alignment", "reference"): ("model",)}
        for section, key in keys:
            value = self.sections.get(section, {}).get(key)
            if value is None or value in skip.get((section, key), ()):
                continue
            if section in ("discover", "alignment") and not self[section]["enabled"]:
                continue
            path = self.resolve(value)
            if not path.is_file() or path.stat().st_size == 0:
                what = ("is a directory" if path.is_dir() else "is empty"
                        if path.is_file() else "not found")
                raise InputError(f"[{section}] {key} = {value!r}: {path} {what}",
                                 file=self.path, column=f"{section}.{key}")

    def as_dict(self) -> dict:
        """The configuration as recorded in provenance (paths as written)."""
        return {"path": str(self.path), "kind": self.kind, **asdict(self)["sections"]}


def _check_type(value, types, where: str, path: Path):
    if isinstance(value, bool) and bool not in (types if isinstance(types, tuple) else (types,)):
        raise InputError(f"{where} must be {_type_names(types)}, not a boolean", file=path)
    if not isinstance(value, types):
        raise InputError(f"{where} must be {_type_names(types)}, got {value!r}", file=path)


def _type_names(types) -> str:
    names = {list: "a list", str: "a string", dict: "a table", bool: "true or false",
             int: "an integer", float: "a number"}
    types = types if isinstance(types, tuple) else (types,)
    return " or ".join(dict.fromkeys(names.get(t, t.__name__) for t in types))


def _section(name: str, given: Any, path: Path) -> dict:
    schema = SCHEMA[name]
    if not isinstance(given, dict):
        raise InputError(f"[{name}] must be a table", file=path)
    unknown = [k for k in given if k not in schema]
    if unknown:
        raise InputError(f"[{name}] unknown key {unknown[0]!r} (known: "
                         f"{', '.join(schema)})", file=path, column=f"{name}.{unknown[0]}")
    out = {}
    for key, (types, default) in schema.items():
        if key in given:
            _check_type(given[key], types, f"[{name}] {key}", path)
            out[key] = given[key]
        elif default is _MISSING:
            raise InputError(f"[{name}] needs the key {key!r}", file=path,
                             column=f"{name}.{key}")
        else:
            out[key] = default
    return out


def parse_chain_config(text: str, path: str | Path) -> ChainConfig:
    """Parse and check the TOML text of a chain configuration.

    Examples
    --------
    >>> cfg = parse_chain_config('[input]\\nfiles = ["raw/*.csv"]\\ntarget = "fgmo"\\n'
    ...                          '[position]\\nlongitude_deg = 128.2\\n', "CHAIN.toml")
    >>> cfg["offsets"]["window_days"], cfg["picog"]["plan"], cfg.kind
    (28.0, 'auto', 'geostationary')
    >>> parse_chain_config('[input]\\nfiles = ["a.csv"]\\nfile = 1\\n', "C.toml")
    Traceback (most recent call last):
    ...
    magcal.errors.InputError: C.toml: column input.file: [input] unknown key 'file' (known: ...)
    """
    path = Path(path)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML ({exc})", file=path) from None
    unknown = [k for k in doc if k not in SCHEMA]
    if unknown:
        raise InputError(f"unknown section [{unknown[0]}] (known: {', '.join(SCHEMA)})",
                         file=path, column=unknown[0])
    if "input" not in doc:
        raise InputError("needs an [input] section with files = [...]", file=path,
                         column="input")
    kind = "spin" if "spin" in doc else "geostationary"
    if kind == "spin":
        extra = [k for k in doc if k not in SPIN_SECTIONS]
        if extra:
            raise InputError(f"section [{extra[0]}] does not apply to a spinning-spacecraft "
                             f"chain (allowed: {', '.join(SPIN_SECTIONS)})", file=path,
                             column=extra[0])
    sections = {name: _section(name, doc.get(name, {}), path) for name in SCHEMA}
    _check_values(sections, path, kind)
    return ChainConfig(path=path, sections=sections, kind=kind)


def _check_values(s: dict, path: Path, kind: str) -> None:
    from magcal.io.formats import FORMATS

    if not s["input"]["files"] or not all(isinstance(f, str) for f in s["input"]["files"]):
        raise InputError("[input] files must be a non-empty list of paths or globs", file=path)
    if s["input"]["format"] not in ("auto",) + FORMATS:
        raise InputError(f"[input] format {s['input']['format']!r}: use auto or one of "
                         f"{', '.join(FORMATS)}", file=path)
    from magcal.alignment.gls import NOISE_MODELS

    if s["alignment"]["noise_model"] not in NOISE_MODELS:
        raise InputError(f"[alignment] noise_model {s['alignment']['noise_model']!r}: use "
                         f"one of {', '.join(NOISE_MODELS)}", file=path,
                         column="alignment.noise_model")
    if s["output"]["format"] not in ("auto", "csv", "netcdf", "cdf"):
        raise InputError(f"[output] format {s['output']['format']!r}: use auto (the input's "
                         "family), csv, netcdf (CF-1.8) or cdf (ISTP)", file=path,
                         column="output.format")
    if kind == "spin":
        _check_spin(s["spin"], path)
        return
    pos = s["position"]
    if pos["longitude_deg"] is None and not pos["columns"]:
        raise InputError("[position] needs longitude_deg (geostationary) or columns = true "
                         "(lon_deg,lat_deg,r_re in the input)", file=path, column="position")
    if s["picog"]["on_worse"] not in ("raw", "keep"):
        raise InputError(f"[picog] on_worse {s['picog']['on_worse']!r}: use raw (deliver the "
                         "uncleaned target when cleaning makes a band worse) or keep",
                         file=path)
    if s["picog"]["fit_days"] <= 0:
        raise InputError("[picog] fit_days must be positive (days of data the frames and "
                         "PiCoG are fitted on)", file=path, column="picog.fit_days")
    if s["picog"]["fit_max_samples"] < 1:
        raise InputError("[picog] fit_max_samples must be at least 1 (the fit's memory grows "
                         "with its samples: about 1.3 kB per two-sensor sample)", file=path,
                         column="picog.fit_max_samples")
    try:
        QCSettings.from_mapping(s["qc"])
    except InputError as exc:
        raise InputError(exc.message, file=path, column=exc.column) from None
    if s["offsets"]["method"] not in ("median", "lt_balanced"):
        raise InputError(f"[offsets] method {s['offsets']['method']!r}: use median or "
                         "lt_balanced", file=path)
    for key in ("window_days", "step_days"):
        if not 0 < s["offsets"][key] < math.inf:
            raise InputError(f"[offsets] {key} must be a positive finite number, got "
                             f"{s['offsets'][key]!r}", file=path, column=f"offsets.{key}")
    _check_numbers(s, path)
    if s["model"]["name"].upper() not in ("IGRF", "T89", "T96", "T01", "T04"):
        raise InputError(f"[model] name {s['model']['name']!r}: use IGRF, T89, T96, T01 or "
                         "T04", file=path)
    for sensor, spec in s["frames"]["to_common"].items():
        if not (spec in ("estimate", "identity") or _is_matrix(spec)):
            raise InputError(f"[frames] to_common.{sensor} must be \"estimate\", \"identity\" "
                             "or a 3x3 matrix (three rows)", file=path)
        if spec == "estimate" and not s["frames"]["reference"]:
            raise InputError("[frames] to_common 'estimate' needs reference = <sensor holding "
                             "the combined field in the common frame>", file=path)
    hp = s["frames"]["to_hpen"]
    if hp is not None and not (hp in ("estimate", "identity") or _is_matrix(hp)):
        raise InputError("[frames] to_hpen must be \"estimate\", \"identity\" or a 3x3 "
                         "matrix", file=path)


#: (section, key) -> (low, high, what): numbers that must be finite and in a range
#: (inclusive) for the chain to mean anything. A Kp threshold of nan or -1 selects no
#: quiet sample and a longitude of 500 deg places the spacecraft nowhere: each used to
#: run to the end (exit 0) or fail a later stage (exit 3) instead of naming the key.
_RANGES = {
    ("position", "longitude_deg"): (-360.0, 360.0, "deg east"),
    ("position", "latitude_deg"): (-90.0, 90.0, "deg"),
    ("position", "r_re"): (1.0, 1000.0, "Earth radii from the centre"),
    ("offsets", "kp_max"): (0.0, 9.0, "Kp"),
    ("offsets", "min_used"): (1, math.inf, "samples"),
    ("offsets", "cadence_s"): (1e-9, math.inf, "s"),
    ("model", "cadence_s"): (1e-9, math.inf, "s"),
    ("model", "jobs"): (1, math.inf, "processes"),
    ("alignment", "kp_max"): (0.0, 9.0, "Kp"),
    ("alignment", "seed"): (0, math.inf, "the MCMC's random seed"),
    ("discover", "max_effects"): (0, math.inf, "effects"),
}


def _check_numbers(s: dict, path: Path) -> None:
    """Every number of :data:`_RANGES` finite and in its range; the alignment's
    ``lt_harmonics`` ("auto" or an integer >= 0) and ``window_days`` ("auto" or a
    positive number of days; 0 for none)."""
    for (section, key), (lo, hi, unit) in _RANGES.items():
        value = s[section][key]
        if value is None:
            continue
        if not (math.isfinite(value) and lo <= value <= hi):
            shown = (f"{lo:g} to {hi:g}" if hi < math.inf else "positive" if 0 < lo < 1e-6
                     else f"at least {lo:g}")
            raise InputError(f"[{section}] {key} must be {shown} ({unit}), got {value!r}",
                             file=path, column=f"{section}.{key}")
    al = s["alignment"]
    lt = al["lt_harmonics"]
    if not (lt == "auto" or (isinstance(lt, int) and not isinstance(lt, bool) and lt >= 0)):
        raise InputError(f"[alignment] lt_harmonics must be \"auto\" or an integer >= 0, got "
                         f"{lt!r}", file=path, column="alignment.lt_harmonics")
    wd = al["window_days"]
    if not (wd == "auto" or (not isinstance(wd, str) and 0 <= wd < math.inf)):
        raise InputError(f"[alignment] window_days must be \"auto\" or a number of days >= 0 "
                         f"(0: no windows), got {wd!r}", file=path,
                         column="alignment.window_days")


def _check_spin(sp: dict, path: Path) -> None:
    """``[spin]``: nT data run the spin-ripple chain; ``units = "counts"`` (ELFIN) needs
    ``reference = "igrf"`` and the ``state`` file, and takes ``pipeline`` switches."""
    if sp["units"] not in ("nT", "counts"):
        raise InputError(f"[spin] units {sp['units']!r}: use nT (spin-ripple calibration) or "
                         "counts (ELFIN FGS counts calibrated against a model field)",
                         file=path, column="spin.units")
    if sp["units"] == "nT":
        given = [k for k in ("reference", "state") if sp[k] is not None]
        given += ["pipeline"] if sp["pipeline"] else []
        given += ["disturbed"] if sp["disturbed"] else []
        if given:
            raise InputError(f"[spin] {given[0]} applies only to units = \"counts\" (the "
                             "ELFIN chain)", file=path, column=f"spin.{given[0]}")
        return
    if sp["reference"] is None or sp["reference"].lower() != "igrf":
        raise InputError("[spin] units = \"counts\" needs reference = \"igrf\" (the model "
                         "field the counts are calibrated against)", file=path,
                         column="spin.reference")
    if not sp["state"]:
        raise InputError("[spin] units = \"counts\" needs state = <ELFIN state file> (orbit "
                         "and attitude)", file=path, column="spin.state")
    _check_intervals(sp["disturbed"], path)
    if sp["spin_period_s"] is not None:
        raise InputError("[spin] spin_period_s does not apply to units = \"counts\": the "
                         "spin phase is derived from the counts", file=path,
                         column="spin.spin_period_s")


def _check_intervals(intervals: list, path: Path) -> None:
    """``[spin] disturbed``: pairs of UTC times, each start before its end."""
    import pandas as pd

    for item in intervals:
        ok = isinstance(item, list) and len(item) == 2 and all(isinstance(v, str) for v in item)
        if ok:
            try:
                start, end = (pd.Timestamp(v) for v in item)
            except ValueError:
                ok = False
            else:
                ok = start < end
        if not ok:
            raise InputError(f"[spin] disturbed: {item!r} is not [start, end] in UTC with "
                             "start before end (e.g. [\"2022-01-12T05:10:00\", "
                             "\"2022-01-12T05:12:00\"])", file=path, column="spin.disturbed")


def _is_matrix(spec) -> bool:
    return (isinstance(spec, list) and len(spec) == 3
            and all(isinstance(r, list) and len(r) == 3 for r in spec)
            and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                    for r in spec for v in r))


def read_chain_config(path: str | Path) -> ChainConfig:
    """Read ``CHAIN.toml`` (see :func:`parse_chain_config`)."""
    p = Path(path)
    if not p.is_file():
        raise InputError("chain configuration not found", file=p)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read as UTF-8 text ({exc})", file=p) from None
    return parse_chain_config(text, p)
