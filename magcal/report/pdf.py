"""Render a :class:`~magcal.report.document.Document` as a PDF with matplotlib alone.

Text and tables are laid out on A4 pages with matplotlib's text engine; figures are
placed one per page from their PNG. No LaTeX or browser is needed.
"""

from __future__ import annotations

import io
import textwrap
from pathlib import Path

from magcal.io.atomic import atomic_path
from magcal.report.document import Document, Figure, Paragraph, Table

_A4 = (8.27, 11.69)
_LINES_PER_PAGE = 62


def _text_lines(doc: Document) -> list[tuple[str, str]]:
    """Flatten non-figure content into (style, line) pairs."""
    lines: list[tuple[str, str]] = [("title", doc.title)]
    if doc.subtitle:
        lines.append(("em", doc.subtitle))
    return lines


def write_pdf(doc: Document, path) -> Path:
    """Write ``doc`` as a PDF (atomically); figures get a page each."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.image as mpimg
    import matplotlib.pyplot as plt
    from matplotlib.backends.backend_pdf import PdfPages

    pages: list[list[tuple[str, str]]] = [[]]
    figures_after: dict[int, list[Figure]] = {}

    def add(style, text):
        # long table rows continue on an indented line instead of running off the page
        parts = (textwrap.wrap(text, 118, subsequent_indent="    ", drop_whitespace=False)
                 if style == "mono" and len(text) > 118 else [text])
        for part in parts:
            if len(pages[-1]) >= _LINES_PER_PAGE:
                pages.append([])
            pages[-1].append((style, part))

    for style, text in _text_lines(doc):
        add(style, text)
    for sec in doc.sections:
        add("h2", sec.title)
        for item in sec.items:
            if isinstance(item, Paragraph):
                for line in textwrap.wrap(item.text, 95) or [""]:
                    add("p", line)
            elif isinstance(item, Table):
                widths = [max(len(c), *(len(r[k]) for r in item.rows)) if item.rows else len(c)
                          for k, c in enumerate(item.columns)]
                add("mono", "  ".join(c.ljust(w) for c, w in zip(item.columns, widths)))
                for row in item.rows:
                    add("mono", "  ".join(c.ljust(w) for c, w in zip(row, widths)))
                if item.caption:
                    add("small", item.caption)
                if item.source:
                    add("small", f"source: {item.source}")
            elif isinstance(item, Figure):
                figures_after.setdefault(len(pages) - 1, []).append(item)
                add("small", f"[figure: {item.caption}]")
            add("p", "")
    styles = {"title": dict(size=16, weight="bold"), "h2": dict(size=12.5, weight="bold"),
              "p": dict(size=9), "em": dict(size=9, style="italic"),
              "mono": dict(size=7.5, family="monospace"), "small": dict(size=7.5, color="0.35")}
    with atomic_path(path) as tmp:
        with PdfPages(tmp) as pdf:
            for k, page in enumerate(pages):
                fig = plt.figure(figsize=_A4)
                y = 0.96
                for style, text in page:
                    fig.text(0.07, y, text, va="top", **styles[style])
                    y -= {"title": 0.03, "h2": 0.022}.get(style, 0.0152)
                pdf.savefig(fig)
                plt.close(fig)
                for item in figures_after.get(k, []):
                    fig = plt.figure(figsize=_A4)
                    ax = fig.add_axes([0.05, 0.15, 0.9, 0.78])
                    ax.imshow(mpimg.imread(io.BytesIO(item.png), format="png"))
                    ax.axis("off")
                    fig.text(0.07, 0.1, "\n".join(textwrap.wrap(item.caption, 100)), size=9)
                    if item.source:
                        fig.text(0.07, 0.05, f"source: {item.source}", size=7, color="0.35")
                    pdf.savefig(fig)
                    plt.close(fig)
    return Path(path)
