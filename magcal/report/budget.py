"""Error budget of a products folder, one per frequency band (issue 21).

The SOSMAG requirements (Magnes et al. 2020, Sect. 7 and Table 1) are stated per band:
an error below 1 nT above 0.1 mHz, an offset error below 5 nT below 0.1 mHz, and an
alignment within 10 deg. Each section of the uncertainty report adds its contributions
(:class:`Contribution`); a contribution that could not be computed carries the reason
instead of a number. Per band the computed contributions are combined as independent
errors (root sum of squares) and set against the requirement; when one is missing the
total is a lower bound and says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ABOVE = "above 0.1 mHz"
BELOW = "below 0.1 mHz"
DIRECTION = "direction"
#: Requirement per band (nT, deg for the direction) and its unit.
REQUIREMENTS = {ABOVE: (1.0, "nT"), BELOW: (5.0, "nT"), DIRECTION: (10.0, "deg")}


@dataclass(frozen=True)
class Contribution:
    """One term of a band's error budget.

    ``value`` is None when not computed; ``note`` then says why, else how it was measured.
    ``combined`` False: shown for information, not added to the band total (for instance
    a spread that the standard error already accounts for).
    """

    band: str
    item: str
    value: float | None
    note: str
    source: str = "-"
    combined: bool = True


def band_total(contributions, band: str) -> tuple[float | None, str]:
    """Root sum of squares of the computed, combined contributions of ``band`` and a
    verdict against its requirement.

    Examples
    --------
    >>> c = [Contribution(BELOW, "offset", 3.0, ""), Contribution(BELOW, "align", 4.0, "")]
    >>> band_total(c, BELOW)
    (5.0, 'EXCEEDS 5 nT')
    >>> band_total(c + [Contribution(BELOW, "model", None, "no reference craft")], BELOW)[1]
    'EXCEEDS 5 nT (lower bound: model not computed)'
    """
    req, unit = REQUIREMENTS[band]
    terms = [c for c in contributions if c.band == band and c.combined]
    values = [c.value for c in terms if c.value is not None and np.isfinite(c.value)]
    missing = [c.item for c in terms if c.value is None or not np.isfinite(c.value)]
    if not values:
        return None, "not computed: " + (", ".join(missing) or "no product") + " missing"
    total = float(np.sqrt(np.sum(np.square(values))))
    verdict = f"{'within' if total < req else 'EXCEEDS'} {req:g} {unit}"
    if missing:
        verdict += " (lower bound: " + ", ".join(missing) + " not computed)"
    return total, verdict


def budget_rows(contributions) -> list[tuple]:
    """Table rows: every contribution, then the band total, band by band; no NaN cell."""
    rows = []
    for band in REQUIREMENTS:
        terms = [c for c in contributions if c.band == band]
        if not terms:
            continue
        unit = REQUIREMENTS[band][1]
        for c in terms:
            value = ("not computed" if c.value is None or not np.isfinite(c.value)
                     else f"{c.value:.3f}")
            rows.append((band, c.item + ("" if c.combined else " (not added)"), value, unit,
                         c.note, c.source))
        total, verdict = band_total(terms, band)
        rows.append((band, "TOTAL (root sum of squares)",
                     "not computed" if total is None else f"{total:.3f}", unit, verdict, "-"))
    return rows
