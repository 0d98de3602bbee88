"""The report document model: sections holding paragraphs, tables and figures.

Every table and figure can carry ``source``: the product file (and key) its numbers
come from, so each number in a report is traceable to a product and its provenance.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from typing import Sequence


@dataclass(frozen=True)
class Paragraph:
    """Plain text (no markup)."""

    text: str


@dataclass(frozen=True)
class Table:
    """A table of already formatted cells, with units in the column names."""

    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    caption: str = ""
    source: str = ""

    @classmethod
    def from_records(cls, columns: Sequence[str], rows: Sequence[Sequence], caption: str = "",
                     source: str = "", fmt: str = "{:.3g}") -> "Table":
        """Format numbers with ``fmt`` and everything else with ``str``; a non-finite
        number is written "not computed" (a report shows no NaN cell)."""
        def cell(v):
            if isinstance(v, float):
                return fmt.format(v) if math.isfinite(v) else "not computed"
            return str(v)
        return cls(tuple(columns), tuple(tuple(cell(v) for v in r) for r in rows), caption,
                   source)


@dataclass(frozen=True)
class Figure:
    """A rendered figure: PNG bytes plus caption."""

    png: bytes
    caption: str = ""
    source: str = ""

    @classmethod
    def from_matplotlib(cls, fig, caption: str = "", source: str = "", dpi: int = 110
                        ) -> "Figure":
        """Render a matplotlib figure to PNG and close it."""
        import matplotlib.pyplot as plt

        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
        plt.close(fig)
        return cls(buf.getvalue(), caption, source)


@dataclass(frozen=True)
class Section:
    """A titled list of items."""

    title: str
    items: tuple = ()


@dataclass
class Document:
    """A report under construction (the only mutable piece: sections are appended).

    Examples
    --------
    >>> doc = Document("Uncertainty report")
    >>> doc.section("Offsets", Paragraph("Median over 28-day windows."))
    >>> [s.title for s in doc.sections]
    ['Offsets']
    """

    title: str
    subtitle: str = ""
    sections: list[Section] = field(default_factory=list)
    provenance: dict = field(default_factory=dict)

    def section(self, title: str, *items) -> None:
        self.sections.append(Section(title, tuple(items)))
