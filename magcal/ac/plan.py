"""PLAN.toml for ``magcal picog fit`` (CONTRACTS §1).

::

    target = "fgmo"                  # sensor whose cleaned data is the product
    alpha_method = "decorrelate"     # optional: or "variance" (Eq. 14 only)
    direction = "coherent"           # optional, every order: "variance" (the paper) or
                                     # "coherent" (ambient-free, see magcal.ac.core)
    highpass_s = 1800                # optional, every order: remove running means first
                                     # order key band_hz = [lo, hi]: fit on an FFT band-pass
                                     # (a spectral line such as the 6 s tone)
    [[stage]]                        # first-order cleaning against one reference
    reference = "amr1"
    sensors = ["fgmo", "fgmi"]
    orders = [ { interval = ["2019-03-04T15:10", "2019-03-04T16:15"] } ]
    [[stage]]                        # iterative cleaning of a pair: i is cleaned with j
    pair = ["fgmo", "fgmi"]
    orders = [ { window_s = 100 }, { window_s = 700 }, { window_s = 16000, cone_deg = 2.5 } ]
    # joint = true                   # optional: one constant 3x3 per sensor fitted jointly
                                     # over the selections of all orders and event
                                     # intervals (magcal.ac.joint); event_half_s = 120
                                     # (0: no events), min_snr = 5, events = "pulse"
                                     # (matched filter on each event's pulse, other
                                     # spikes masked, ambient waves removed, events
                                     # pooled; kept from pulse_min_snr = 2.5) or
                                     # "interval" (whole intervals free of other events)
    [[stage]]                        # extension: non-orthogonal regression gradiometer
    regression = ["fgmo"]
    references = ["fgmi", "amr1"]
    orders = [ { detrend_s = 3600 } ]

Interval times are ISO-8601 UTC; they become seconds since 1970-01-01 UTC, the time
base :class:`magcal.ac.estimator.PiCoG` uses. ``direction`` and ``highpass_s`` may also
be given per order (``highpass_s = 0`` switches filtering off); without them an order
follows the paper (maximum-variance direction of the sensor, no filtering); the
plan-level ``direction`` and ``highpass_s`` are defaults of the PiCoG (reference and
pair) orders. A key that a part of the plan does not use (``band_hz`` or ``window_s``
in a regression order, ``detrend_s`` in a PiCoG order, event keys of a pair stage
without ``joint = true``, a misspelt key) is refused with the key and the stage named,
never ignored. With a
varying ambient field (daily variation, substorms) use ``direction = "coherent"`` and
``highpass_s = 1800``: on the simulated GK-2A-like day this takes the contract's plan
from 3x to about 290x disturbance-power reduction.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pandas as pd

from magcal.ac.chain import Order, Plan, Stage
from magcal.ac.core import DIRECTION_METHODS
from magcal.errors import InputError, not_a_file_error

_NAME = re.compile(r"^[a-z0-9_]+$")


def to_epoch_s(value, *, file=None) -> float:
    """ISO-8601 UTC string or Timestamp -> seconds since 1970-01-01 UTC.

    Examples
    --------
    >>> to_epoch_s("1970-01-01T00:01:00")
    60.0
    """
    try:
        ts = pd.Timestamp(value)
    except (ValueError, TypeError):
        raise InputError(f"cannot parse time {value!r} as ISO-8601 UTC", file=file) from None
    if ts.tzinfo is None:
        ts = ts.tz_localize("UTC")
    return ts.value / 1e9


#: Keys each part of a plan understands; anything else is refused (exit 2), not ignored.
PLAN_KEYS = frozenset({"target", "alpha_method", "direction", "highpass_s", "stage"})
_PICOG_ORDER = frozenset({"interval", "window_s", "cone_deg", "direction", "highpass_s",
                          "band_hz"})
ORDER_KEYS = {"reference": _PICOG_ORDER, "pair": _PICOG_ORDER,
              "regression": frozenset({"interval", "detrend_s"})}
JOINT_STAGE_KEYS = frozenset({"joint", "event_half_s", "min_snr", "pulse_min_snr", "events"})
STAGE_KEYS = {"reference": frozenset({"reference", "sensors", "orders"}),
              "pair": frozenset({"pair", "orders"}) | JOINT_STAGE_KEYS,
              "regression": frozenset({"regression", "references", "orders"})}


def _check_keys(table: dict, allowed, file, where: str, what: str) -> None:
    """InputError naming the first key of ``table`` that ``what`` does not understand.

    Examples
    --------
    >>> _check_keys({"band_hz": [1, 2]}, ORDER_KEYS["regression"], None, "stage 1 order 1",
    ...             "an order of a regression stage")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    magcal.errors.InputError: stage 1 order 1: key 'band_hz' is not supported in an order ...
    """
    for key in table:
        if key not in allowed:
            raise InputError(f"{where}: key {key!r} is not supported in {what} (supported: "
                             f"{', '.join(sorted(allowed))})", file=file)


def _check_name(name, file, where):
    if not isinstance(name, str) or not _NAME.match(name):
        raise InputError(f"{where}: sensor name {name!r} must be lowercase letters, digits "
                         "or '_'", file=file)
    return name


def _order(spec, file, where, defaults=None, kind="pair") -> Order:
    if not isinstance(spec, dict):
        raise InputError(f"{where}: each order must be a table like {{ window_s = 100 }}",
                         file=file)
    _check_keys(spec, ORDER_KEYS[kind], file, where, f"an order of a {kind} stage")
    interval = None
    if "interval" in spec:
        iv = spec["interval"]
        if not (isinstance(iv, list) and len(iv) == 2):
            raise InputError(f"{where}: interval must be [start, end]", file=file)
        interval = (to_epoch_s(iv[0], file=file), to_epoch_s(iv[1], file=file))
        if not interval[1] > interval[0]:
            raise InputError(f"{where}: interval end must be after its start", file=file)
    window_s = spec.get("window_s")
    if window_s is not None and not (isinstance(window_s, (int, float)) and window_s > 0):
        raise InputError(f"{where}: window_s must be a positive number of seconds", file=file)
    cone = spec.get("cone_deg", 2.5)
    if not (isinstance(cone, (int, float)) and 0 < cone <= 90):
        raise InputError(f"{where}: cone_deg must be in (0, 90]", file=file)
    detrend = spec.get("detrend_s")
    band = spec.get("band_hz")
    if band is not None:
        if not (isinstance(band, list) and len(band) == 2
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in band)
                and 0 <= band[0] < band[1]):
            raise InputError(f"{where}: band_hz must be [low, high] in Hz with "
                             "0 <= low < high", file=file)
        band = (float(band[0]), float(band[1]))
    defaults = defaults or {}
    direction = _direction(spec.get("direction", defaults.get("direction", "variance")),
                           file, where)
    hp = _highpass(spec.get("highpass_s", defaults.get("highpass_s")), file, where)
    return Order(window_s=None if window_s is None else float(window_s), interval=interval,
                 cone_deg=float(cone), detrend_s=None if detrend is None else float(detrend),
                 direction=direction, highpass_s=hp, band_hz=band)


def _direction(value, file, where) -> str:
    if value not in DIRECTION_METHODS:
        raise InputError(f"{where}: direction must be one of {list(DIRECTION_METHODS)}, got "
                         f"{value!r}", file=file)
    return value


def _highpass(value, file, where) -> float | None:
    if value is None or value == 0:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise InputError(f"{where}: highpass_s must be a positive number of seconds (0: "
                         "off)", file=file)
    return float(value)


def plan_from_dict(doc: dict, *, file=None) -> tuple[Plan, dict]:
    """Build a :class:`Plan` from a parsed TOML document; also return options.

    Examples
    --------
    >>> plan, opts = plan_from_dict({"target": "fgmo", "stage": [
    ...     {"pair": ["fgmo", "fgmi"], "orders": [{"window_s": 100}]}]})
    >>> plan.stages[0].kind, plan.stages[0].orders[0].window_s
    ('pair', 100.0)
    """
    if "target" not in doc:
        raise InputError("missing 'target'", file=file)
    target = _check_name(doc["target"], file, "target")
    defaults = {"direction": _direction(doc.get("direction", "variance"), file, "plan"),
                "highpass_s": _highpass(doc.get("highpass_s"), file, "plan")}
    stages = []
    _check_keys(doc, PLAN_KEYS, file, "plan", "the top level of a plan")
    stage_list = doc.get("stage", [])
    if not isinstance(stage_list, list):
        raise InputError("'stage' must be an array of tables ([[stage]])", file=file)
    for k, st in enumerate(stage_list, start=1):
        where = f"stage {k}"
        if not isinstance(st, dict):
            raise InputError(f"{where}: must be a table ([[stage]])", file=file)
        kinds = [key for key in ("reference", "pair", "regression") if key in st]
        if len(kinds) != 1:
            raise InputError(f"{where}: give exactly one of 'reference' (with 'sensors'), "
                             "'pair' or 'regression' (with 'references')", file=file)
        kind = kinds[0]
        where = f"stage {k} ({kind})"
        _check_keys(st, STAGE_KEYS[kind], file, where, f"a {kind} stage")
        if kind == "pair" and st.get("joint") is not True:
            extra = sorted(set(st) & (JOINT_STAGE_KEYS - {"joint"}))
            if extra:
                raise InputError(f"{where}: key {extra[0]!r} only applies with joint = true",
                                 file=file)
        order_list = st.get("orders", [{}])
        if not isinstance(order_list, list) or not order_list:
            raise InputError(f"{where}: orders must be a non-empty array of tables", file=file)
        orders = tuple(_order(o, file, f"{where} order {n}", defaults, kind)
                       for n, o in enumerate(order_list, start=1))
        if kind == "reference":
            sensors = tuple(_check_name(s, file, where) for s in st.get("sensors", []))
            ref = _check_name(st["reference"], file, where)
            stages.append(Stage("reference", sensors, reference=ref, orders=orders))
        elif kind == "pair":
            pair = st["pair"]
            if not (isinstance(pair, list) and len(pair) == 2):
                raise InputError(f"{where}: pair must list two sensors", file=file)
            joint = st.get("joint", False)
            if not isinstance(joint, bool):
                raise InputError(f"{where}: joint must be true or false", file=file)
            extra = {}
            for key in ("event_half_s", "min_snr", "pulse_min_snr"):
                if key in st:
                    v = st[key]
                    if isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0:
                        raise InputError(f"{where}: {key} must be a number >= 0", file=file)
                    extra[key] = float(v) if (v or key != "event_half_s") else None
            if "events" in st:
                if st["events"] not in ("pulse", "interval"):
                    raise InputError(f"{where}: events must be \"pulse\" or \"interval\", "
                                     f"got {st['events']!r}", file=file)
                extra["events"] = st["events"]
            stages.append(Stage("pair", tuple(_check_name(s, file, where) for s in pair),
                                orders=orders, joint=joint, **extra))
        else:
            sensors = tuple(_check_name(s, file, where) for s in st["regression"])
            refs = tuple(_check_name(s, file, where) for s in st.get("references", []))
            stages.append(Stage("regression", sensors, references=refs, orders=orders))
    if not stages:
        raise InputError("the plan has no [[stage]]", file=file)
    plan = Plan(target=target, stages=tuple(stages))
    if not any(target in st.sensors for st in plan.stages):
        raise InputError(f"target {target!r} is not cleaned by any stage", file=file)
    alpha_method = doc.get("alpha_method", "decorrelate")
    if alpha_method not in ("decorrelate", "variance"):
        raise InputError("alpha_method must be 'decorrelate' or 'variance'", file=file)
    return plan, {"alpha_method": alpha_method}


def read_plan(path) -> tuple[Plan, dict]:
    """Read and validate a PLAN.toml file."""
    p = Path(path)
    if not p.is_file():
        raise not_a_file_error(p)
    try:
        doc = tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML: {exc}", file=p) from None
    return plan_from_dict(doc, file=p)


def plan_to_dict(plan: Plan) -> dict:
    """JSON-ready description of a plan (kept in PARAMS.json)."""
    stages = []
    for st in plan.stages:
        d = {"kind": st.kind, "sensors": list(st.sensors)}
        if st.reference:
            d["reference"] = st.reference
        if st.references:
            d["references"] = list(st.references)
        if st.joint:
            d.update(joint=True, event_half_s=st.event_half_s, min_snr=st.min_snr,
                     events=st.events, pulse_min_snr=st.pulse_min_snr)
        d["orders"] = [{"window_s": o.window_s,
                        "interval": list(o.interval) if o.interval else None,
                        "cone_deg": o.cone_deg, "detrend_s": o.detrend_s,
                        "direction": o.direction, "highpass_s": o.highpass_s,
                        "band_hz": list(o.band_hz) if o.band_hz else None}
                       for o in st.orders]
        stages.append(d)
    return {"target": plan.target, "stages": stages}


#: Stage keys of a joint pair stage, as :func:`plan_to_dict` writes them
JOINT_KEYS = ("joint", "event_half_s", "min_snr", "events", "pulse_min_snr")


def plan_from_json(doc: dict, *, shift_s: float = 0.0) -> Plan:
    """Inverse of :func:`plan_to_dict` (the ``plan`` kept in PARAMS.json).

    ``shift_s`` moves interval orders (e.g. by whole days for a daily refit).

    Examples
    --------
    >>> plan = Plan("o", (Stage("pair", ("o", "i"), joint=True,
    ...                         orders=(Order(interval=(0.0, 10.0)),)),))
    >>> back = plan_from_json(plan_to_dict(plan), shift_s=5.0)
    >>> back.stages[0].orders[0].interval, back.stages[0].events == plan.stages[0].events
    ((5.0, 15.0), True)
    """
    stages = []
    for st in doc["stages"]:
        orders = []
        for o in st["orders"]:
            iv = o.get("interval")
            orders.append(Order(
                window_s=o.get("window_s"),
                interval=None if iv is None else (iv[0] + shift_s, iv[1] + shift_s),
                cone_deg=o.get("cone_deg", 2.5), detrend_s=o.get("detrend_s"),
                direction=o.get("direction", "variance"), highpass_s=o.get("highpass_s"),
                band_hz=None if o.get("band_hz") is None else tuple(o["band_hz"])))
        joint = {k: st[k] for k in JOINT_KEYS if k in st}
        stages.append(Stage(st["kind"], tuple(st["sensors"]), reference=st.get("reference"),
                            references=tuple(st.get("references", ())), orders=tuple(orders),
                            **joint))
    return Plan(doc["target"], tuple(stages))

