"""Self-contained reports: one document model, rendered to HTML (plots embedded) and PDF.

Build a :class:`~magcal.report.document.Document` from paragraphs, tables and
matplotlib figures (each item may name the product file its numbers come from), then
write it with :func:`~magcal.report.html.write_html` and
:func:`~magcal.report.pdf.write_pdf`.
"""

from magcal.report.document import Document, Figure, Paragraph, Table
from magcal.report.html import write_html
from magcal.report.pdf import write_pdf

__all__ = ["Document", "Figure", "Paragraph", "Table", "write_html", "write_pdf"]
