"""Render a :class:`~gyrolab.report.document.Document` to PDF with matplotlib's PdfPages.

Same content as the HTML page: a title page with the summary, then every section in order,
tables drawn as pages of text tables (split across pages when long) and every figure as a
vector page of its own. No browser is needed, so the PDF is written everywhere the HTML is.
"""

from __future__ import annotations

import os
import textwrap
from collections.abc import Sequence

from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure

from gyrolab.report.document import Document, FigureBlock, TableBlock, TextBlock

A4 = (8.27, 11.69)
ROWS_PER_PAGE = 38
ACCENT = "#1f4e79"


def _page() -> Figure:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = Figure(figsize=A4)
    FigureCanvasAgg(fig)
    return fig


def _clip(cell: str, width: int) -> str:
    cell = str(cell).replace("\n", " ")
    return cell if len(cell) <= width else cell[: width - 1] + "…"


def _table_pages(block: TableBlock, heading: str) -> list[Figure]:
    """One or more A4 pages holding ``block`` (the header repeats on every page)."""
    rows: Sequence[Sequence[str]] = block.rows or [["(none)"] + [""] * (len(block.header) - 1)]
    ncol = max(1, len(block.header))
    # The first column holds labels (metric names, dotted keys): give it more room.
    first = 48 if ncol > 1 else 120
    rest = max(12, (150 - first) // max(1, ncol - 1))
    widths = [first] + [rest] * (ncol - 1)
    pages = []
    for start in range(0, len(rows), ROWS_PER_PAGE):
        chunk = rows[start : start + ROWS_PER_PAGE]
        fig = _page()
        fig.text(0.06, 0.96, heading, fontsize=13, color=ACCENT, weight="bold")
        cont = " (continued)" if start else ""
        fig.text(0.06, 0.935, block.title + cont, fontsize=11, weight="bold")
        h = min(0.86, 0.022 * (len(chunk) + 1))
        ax = fig.add_axes((0.06, 0.92 - h, 0.88, h))
        ax.axis("off")
        tab = ax.table(
            cellText=[[_clip(c, w) for c, w in zip(r, widths, strict=True)] for r in chunk],
            colLabels=[_clip(c, w) for c, w in zip(block.header, widths, strict=True)],
            loc="upper left",
            cellLoc="left",
        )
        tab.auto_set_font_size(False)
        tab.set_fontsize(7.5)
        tab.auto_set_column_width(list(range(ncol)))
        for (r, _c), cell in tab.get_celld().items():
            cell.set_edgecolor("#bbbbbb")
            if r == 0:
                cell.set_facecolor("#e8eef5")
        if block.note:
            fig.text(
                0.06,
                0.03,
                textwrap.fill(block.note, 110),
                fontsize=8,
                color="#555555",
                va="bottom",
            )
        pages.append(fig)
    return pages


def _text_page(title: str, subtitle: str, summary: list[tuple[str, str]]) -> Figure:
    fig = _page()
    fig.text(0.06, 0.93, title, fontsize=18, color=ACCENT, weight="bold")
    fig.text(0.06, 0.905, subtitle, fontsize=10, color="#555555")
    y = 0.86
    for k, v in summary:
        fig.text(0.06, y, k, fontsize=10, color="#555555")
        fig.text(0.40, y, textwrap.shorten(str(v), 70), fontsize=10, weight="bold")
        y -= 0.025
    return fig


def write_pdf(doc: Document, path: str | os.PathLike[str]) -> int:
    """Write ``doc`` to ``path``; returns the number of pages."""
    n = 0
    with PdfPages(path, metadata={"Title": doc.title, "Creator": "gyrolab"}) as pdf:
        pdf.savefig(_text_page(doc.title, doc.subtitle, doc.summary))
        n += 1
        for sec in doc.sections:
            texts = [b.text for b in sec.blocks if isinstance(b, TextBlock)]
            if texts:
                fig = _page()
                fig.text(0.06, 0.96, sec.title, fontsize=13, color=ACCENT, weight="bold")
                fig.text(
                    0.06,
                    0.93,
                    "\n\n".join(textwrap.fill(t, 100) for t in texts),
                    fontsize=9,
                    va="top",
                )
                pdf.savefig(fig)
                n += 1
            for b in sec.blocks:
                if isinstance(b, TableBlock):
                    for page in _table_pages(b, sec.title):
                        pdf.savefig(page)
                        n += 1
                elif isinstance(b, FigureBlock):
                    cap = None
                    if b.caption:
                        # The caption goes under the axes for this page only: the same
                        # figure is also rendered to the HTML, which has its own caption.
                        cap = b.figure.supxlabel(
                            textwrap.fill(b.caption, 130), fontsize=7, color="#555555"
                        )
                    pdf.savefig(b.figure)
                    if cap is not None:
                        cap.set_text("")
                        cap.set_visible(False)
                    n += 1
    return n
