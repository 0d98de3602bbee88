"""Report rendering: HTML is self-contained and carries every number; PDF has the pages."""

import base64
import re

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from magcal.report import Document, Figure, Paragraph, Table, write_html, write_pdf  # noqa: E402


def _doc():
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    doc = Document("Uncertainty report", subtitle="simulated")
    doc.section("Offsets", Paragraph("Median of data minus model on quiet days."),
                Table.from_records(["window", "Hp (nT)"], [["2019-11", 1.23456]],
                                   caption="offsets", source="offsets.csv:Hp"),
                Figure.from_matplotlib(fig, caption="offset time series", source="offsets.csv"))
    doc.provenance = {"magcal_version": "x"}
    return doc


def test_html_is_self_contained_and_traceable(tmp_path):
    path = write_html(_doc(), tmp_path / "r.html")
    text = path.read_text()
    assert "<td>1.23</td>" in text and "source: offsets.csv:Hp" in text
    png = re.search(r'src="data:image/png;base64,([^"]+)"', text).group(1)
    assert base64.b64decode(png)[:8] == b"\x89PNG\r\n\x1a\n"
    assert "http://" not in text and "https://" not in text  # nothing to fetch


def test_pdf_has_text_and_figure_pages(tmp_path):
    path = write_pdf(_doc(), tmp_path / "r.pdf")
    data = path.read_bytes()
    assert data[:5] == b"%PDF-"
    assert len(re.findall(rb"/Type\s*/Page\b", data)) == 2
