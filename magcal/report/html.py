"""Render a :class:`~magcal.report.document.Document` as one self-contained HTML file."""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

from magcal.io.atomic import atomic_path
from magcal.report.document import Document, Figure, Paragraph, Table

_CSS = """
body { font-family: system-ui, sans-serif; max-width: 60rem; margin: 2rem auto; color: #222;
       line-height: 1.45; padding: 0 1rem; }
h1 { border-bottom: 2px solid #345; padding-bottom: .3rem; }
h2 { margin-top: 2.2rem; color: #234; }
table { border-collapse: collapse; margin: .8rem 0; font-size: .92rem; }
th, td { border: 1px solid #bbb; padding: .25rem .6rem; text-align: right; }
th { background: #eef2f6; } td:first-child, th:first-child { text-align: left; }
figure { margin: 1rem 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption, caption { font-size: .88rem; color: #444; caption-side: bottom; text-align: left; }
.source { font-size: .78rem; color: #777; font-family: monospace; }
pre { background: #f6f6f6; padding: .6rem; overflow-x: auto; font-size: .78rem; }
"""


def _source(src: str) -> str:
    return f'<div class="source">source: {html.escape(src)}</div>' if src else ""


def render_html(doc: Document) -> str:
    """The HTML text of ``doc`` (figures embedded as base64 PNG)."""
    out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
           f"<title>{html.escape(doc.title)}</title><style>{_CSS}</style></head><body>",
           f"<h1>{html.escape(doc.title)}</h1>"]
    if doc.subtitle:
        out.append(f"<p><em>{html.escape(doc.subtitle)}</em></p>")
    for sec in doc.sections:
        out.append(f"<h2>{html.escape(sec.title)}</h2>")
        for item in sec.items:
            if isinstance(item, Paragraph):
                out.append(f"<p>{html.escape(item.text)}</p>")
            elif isinstance(item, Table):
                head = "".join(f"<th>{html.escape(c)}</th>" for c in item.columns)
                body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row)
                               + "</tr>" for row in item.rows)
                cap = f"<caption>{html.escape(item.caption)}</caption>" if item.caption else ""
                out.append(f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody>"
                           f"</table>{_source(item.source)}")
            elif isinstance(item, Figure):
                data = base64.b64encode(item.png).decode("ascii")
                out.append(f'<figure><img alt="{html.escape(item.caption)}" '
                           f'src="data:image/png;base64,{data}"><figcaption>'
                           f"{html.escape(item.caption)}</figcaption>{_source(item.source)}"
                           "</figure>")
            else:
                raise TypeError(f"cannot render {type(item).__name__}")
    if doc.provenance:
        out.append("<h2>Provenance</h2><pre>"
                   + html.escape(json.dumps(doc.provenance, indent=2, default=str)) + "</pre>")
    out.append("</body></html>")
    return "\n".join(out)


def write_html(doc: Document, path) -> Path:
    """Write ``doc`` as a self-contained HTML file (atomically)."""
    text = render_html(doc)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)
