"""Render a :class:`~gyrolab.report.document.Document` to an A4 PDF with matplotlib.

Same content as the HTML page, laid out as a document: every page is A4 portrait with a
running header (``Document.running_header``: unit serial and run id, and the section) and
a footer with "page N of M". Text and tables flow down the page; a table's caption is
drawn above it and kept with its first rows (a table that does not fit starts a new page,
one longer than a page continues on the next with its header repeated). Figures flow too,
scaled to the text column's width (aspect kept, at most ``FIG_MAX_H`` of the page high),
with their number and title above and caption below: each figure is saved as a vector PDF
at its own size and drawn into its box on the page with pypdf, so it stays vector and its
layout is the one the HTML shows. No browser is needed.
"""

from __future__ import annotations

import os
import textwrap
from dataclasses import dataclass
from typing import Any

from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from gyrolab.report.document import Document, FigureBlock, TableBlock, TextBlock

A4 = (210 / 25.4, 297 / 25.4)  # inches, portrait (595.3 × 841.9 pt)
ACCENT = "#1f4e79"
MUTED = "#555555"
LEFT, RIGHT = 0.07, 0.93  # text column, fractions of the page width
TOP, BOTTOM = 0.93, 0.06  # flow area below the running header, above the footer
ROW_H = 0.0150  # table row height (7.5 pt text)
LINE_H = 0.0150  # body text line height (9 pt)
CHAR_W = 0.0070  # mean width of a 7.5 pt character, fraction of the page width
PAD = 3  # characters between columns
STATUS_COLORS = {
    "complete": "#2e7d32",
    "aborted": "#e65100",
    "interrupted": "#e65100",
    "recovered": "#c62828",
    "incomplete": "#c62828",
}


def _new_page() -> Figure:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = Figure(figsize=A4)
    FigureCanvasAgg(fig)
    return fig


@dataclass
class _Flow:
    """The page being filled and the vertical position (figure fraction) to draw at."""

    pages: list[tuple[Figure, str]]
    y: float = TOP
    section: str = ""

    @property
    def page(self) -> Figure:
        return self.pages[-1][0]

    def new_page(self) -> Figure:
        self.pages.append((_new_page(), self.section))
        self.y = TOP
        return self.page

    def room(self) -> float:
        return self.y - BOTTOM

    def need(self, h: float) -> Figure:
        """The current page if ``h`` still fits on it, else a fresh one."""
        if not self.pages or self.room() < h:
            self.new_page()
        return self.page


def _clip(cell: str, n: int) -> str:
    cell = str(cell).replace("\n", " ")
    return cell if len(cell) <= n else cell[: max(1, n - 1)] + "…"


def _is_num(cell: str) -> bool:
    try:
        float(str(cell).replace("−", "-"))
    except ValueError:
        return False
    return True


def _col_chars(block: TableBlock) -> list[int]:
    """Characters per column: the longest cell, shrunk to fit the page width."""
    ncol = max(1, len(block.header))
    # bold header characters are ~15 % wider than the body's
    widest = [int(len(str(h)) * 1.15) + 1 for h in block.header] or [1]
    for r in block.rows:
        for i, c in enumerate(r[:ncol]):
            widest[i] = max(widest[i], len(str(c)))
    budget = int((RIGHT - LEFT) / CHAR_W) - PAD * ncol
    chars = [max(3, min(w, 90)) for w in widest]
    while sum(chars) > budget:
        i = max(range(ncol), key=lambda k: chars[k])
        chars[i] -= 1
    return chars


def _table(flow: _Flow, block: TableBlock, number: int) -> None:
    """Caption above, header, rows; continues on the next page when it runs out of room."""
    rows = block.rows or [["(none)"] + [""] * (len(block.header) - 1)]
    chars = _col_chars(block)
    xs = [LEFT]
    for c in chars[:-1]:
        xs.append(xs[-1] + (c + PAD) * CHAR_W)
    width = sum((c + PAD) * CHAR_W for c in chars)
    numeric = [
        block.align_numbers and any(_is_num(str(r[i])) for r in block.rows if i < len(r))
        for i in range(len(chars))
    ]
    note = textwrap.wrap(block.note, 115) if block.note else []
    start = 0
    while start < len(rows):
        # caption + header + at least 3 rows (or all) stay together
        first = min(len(rows) - start, 3)
        fig = flow.need(0.03 + ROW_H * (1 + first))
        cont = " (continued)" if start else ""
        fig.text(
            LEFT,
            flow.y,
            f"Table {number}. {block.title}{cont}",
            fontsize=9.5,
            weight="bold",
            va="top",
        )
        flow.y -= 0.022
        fit = int((flow.room() - ROW_H) // ROW_H)
        chunk = rows[start : start + max(1, fit)]
        for r_i, row in enumerate([block.header, *chunk]):
            y = flow.y - r_i * ROW_H
            if r_i == 0:
                fig.add_artist(
                    Rectangle(
                        (LEFT - 0.004, y - ROW_H),
                        width,
                        ROW_H,
                        transform=fig.transFigure,
                        color="#e8eef5",
                        lw=0,
                    )
                )
            else:
                fig.add_artist(_hline(fig, LEFT - 0.004, LEFT - 0.004 + width, y))
            if not block.rows and r_i > 0:  # an empty table says so, across its width
                fig.text(xs[0], y - ROW_H / 2, "(none)", fontsize=7.5, va="center")
                continue
            for c_i, cell in enumerate(list(row)[: len(chars)]):
                text = _clip(cell, chars[c_i])
                right = numeric[c_i] and (r_i == 0 or _is_num(text))
                x = xs[c_i] + chars[c_i] * CHAR_W if right else xs[c_i]
                fig.text(
                    x,
                    y - ROW_H / 2,
                    text,
                    fontsize=7.5,
                    va="center",
                    ha="right" if right else "left",
                    weight="bold" if r_i == 0 else "normal",
                )
        flow.y -= ROW_H * (len(chunk) + 1)
        start += len(chunk)
        if start >= len(rows) and note:
            if flow.room() < LINE_H * len(note) + 0.005:
                flow.new_page()
            fig = flow.page
            fig.text(LEFT, flow.y - 0.004, "\n".join(note), fontsize=7.5, color=MUTED, va="top")
            flow.y -= LINE_H * 0.85 * len(note) + 0.006
        flow.y -= 0.018


def _hline(fig: Figure, x0: float, x1: float, y: float) -> Any:
    from matplotlib.lines import Line2D

    return Line2D([x0, x1], [y, y], transform=fig.transFigure, color="#cccccc", lw=0.5)


def _text(flow: _Flow, text: str, kind: str) -> None:
    lines = textwrap.wrap(text, 105) or [""]
    h = LINE_H * len(lines) + 0.008
    fig = flow.need(h)
    color = "#7a5a00" if kind == "note" else "k"
    if kind == "note":
        fig.add_artist(
            Rectangle(
                (LEFT - 0.008, flow.y - h + 0.002),
                RIGHT - LEFT + 0.016,
                h,
                transform=fig.transFigure,
                color="#fff8e1",
                lw=0,
            )
        )
    fig.text(LEFT, flow.y, "\n".join(lines), fontsize=9, va="top", color=color, linespacing=1.35)
    flow.y -= h + 0.008


def _heading(flow: _Flow, title: str, then: float = 0.05) -> None:
    """A section title, kept with the first ``then`` of what follows it."""
    fig = flow.need(0.032 + then)
    fig.text(LEFT, flow.y, title, fontsize=13, color=ACCENT, weight="bold", va="top")
    flow.y -= 0.032


def _title(flow: _Flow, doc: Document) -> None:
    fig = flow.new_page()
    fig.text(LEFT, flow.y, doc.title, fontsize=17, color=ACCENT, weight="bold", va="top")
    fig.text(LEFT, flow.y - 0.032, doc.subtitle, fontsize=10, color=MUTED, va="top")
    flow.y -= 0.065
    for k, v in doc.summary:
        lines = textwrap.wrap(str(v), 68) or [""]
        color = "k"
        if k == "run outcome":
            color = STATUS_COLORS.get(doc.status, "k")
        elif k == "verdict" and str(v).startswith(("PASS", "FAIL")):
            color = "#2e7d32" if str(v).startswith("PASS") else "#c62828"
        fig.text(LEFT, flow.y, k, fontsize=9.5, color=MUTED, va="top")
        fig.text(
            0.33,
            flow.y,
            "\n".join(lines),
            fontsize=9.5,
            weight="bold",
            va="top",
            color=color,
            linespacing=1.3,
        )
        flow.y -= 0.0175 * len(lines) + 0.004
    flow.y -= 0.02


FIG_MAX_H = 0.62  # a figure takes at most this share of the page height


def _figure_box(block: FigureBlock) -> tuple[float, float, list[str]]:
    """(width, height) in page fractions for ``block`` at the column's width (aspect kept,
    narrowed when taller than ``FIG_MAX_H``) and its caption's lines."""
    w0, h0 = block.figure.get_size_inches()
    width = RIGHT - LEFT
    height = width * A4[0] * h0 / w0 / A4[1]
    if height > FIG_MAX_H:
        width *= FIG_MAX_H / height
        height = FIG_MAX_H
    cap = textwrap.wrap(block.caption, 115) if block.caption else []
    return width, height, cap


def _figure_height(block: FigureBlock) -> float:
    _, height, cap = _figure_box(block)
    return 0.024 + height + 0.008 + 0.0125 * len(cap)


@dataclass
class _Placement:
    """Where a figure's own (vector) PDF page is drawn: page index, box in page fractions."""

    page: int
    block: FigureBlock
    box: tuple[float, float, float, float]  # x0, y0, width, height


def _figure(flow: _Flow, block: FigureBlock, number: int, placements: list[_Placement]) -> None:
    """Number and title above, a box for the figure, the caption below; the figure itself
    is merged into the box afterwards (:func:`_merge_figures`), so it stays vector."""
    width, height, cap = _figure_box(block)
    fig = flow.need(_figure_height(block))
    fig.text(LEFT, flow.y, f"Figure {number}. {block.title}", fontsize=9.5, weight="bold", va="top")
    top = flow.y - 0.024
    x0 = LEFT + (RIGHT - LEFT - width) / 2
    placements.append(_Placement(len(flow.pages) - 1, block, (x0, top - height, width, height)))
    y = top - height - 0.008
    if cap:
        fig.text(LEFT, y, "\n".join(cap), fontsize=7.5, color=MUTED, va="top", linespacing=1.3)
    flow.y = y - 0.0125 * len(cap) - 0.02


def _merge_figures(pdf_bytes: bytes, placements: list[_Placement], path: Any, title: str) -> None:
    """Draw each figure (saved as a vector PDF at its own size) into its box."""
    import io

    from pypdf import PdfReader, PdfWriter, Transformation

    writer = PdfWriter(clone_from=PdfReader(io.BytesIO(pdf_bytes)))
    pw, ph = (72 * A4[0], 72 * A4[1])
    for pl in placements:
        buf = io.BytesIO()
        pl.block.figure.savefig(buf, format="pdf", metadata={"Creator": None, "Producer": None})
        src = PdfReader(io.BytesIO(buf.getvalue())).pages[0]
        x0, y0, w, _h = pl.box
        scale = w * pw / float(src.mediabox.width)
        ctm = Transformation().scale(scale, scale).translate(x0 * pw, y0 * ph)
        writer.pages[pl.page].merge_transformed_page(src, ctm)
    writer.add_metadata({"/Title": title, "/Creator": "gyrolab"})
    with open(path, "wb") as fh:
        writer.write(fh)


def _furniture(fig: Figure, doc: Document, section: str, n: int, total: int) -> list[Any]:
    """Running header (unit serial · run id, section) and footer (page N of M)."""
    head = doc.running_header or doc.title
    return [
        fig.text(LEFT, 0.965, head, fontsize=7.5, color=MUTED, va="bottom"),
        fig.text(RIGHT, 0.965, section, fontsize=7.5, color=MUTED, va="bottom", ha="right"),
        fig.add_artist(_hline(fig, LEFT, RIGHT, 0.96)),
        fig.text(LEFT, 0.035, f"gyrolab — {doc.title}", fontsize=7, color=MUTED),
        fig.text(RIGHT, 0.035, f"page {n} of {total}", fontsize=7.5, color=MUTED, ha="right"),
    ]


def _first_height(block: Any) -> float:
    """Room the first block of a section needs, so that its heading is not left alone."""
    if isinstance(block, FigureBlock):
        return _figure_height(block)
    if isinstance(block, TableBlock):
        return 0.03 + ROW_H * (1 + min(3, max(1, len(block.rows))))
    if isinstance(block, TextBlock):
        return LINE_H * min(4, len(textwrap.wrap(block.text, 105)) or 1)
    return 0.05


def write_pdf(doc: Document, path: str | os.PathLike[str]) -> int:
    """Write ``doc`` to ``path`` as A4 pages; returns the number of pages."""
    import io

    flow = _Flow(pages=[])
    _title(flow, doc)
    placements: list[_Placement] = []
    n_fig = n_tab = 0
    for sec in doc.sections:
        flow.section = sec.title
        _heading(flow, sec.title, _first_height(sec.blocks[0]) if sec.blocks else 0.05)
        for b in sec.blocks:
            if isinstance(b, FigureBlock):
                n_fig += 1
                _figure(flow, b, n_fig, placements)
            elif isinstance(b, TableBlock):
                n_tab += 1
                _table(flow, b, n_tab)
            elif isinstance(b, TextBlock):
                _text(flow, b.text, b.kind)
    total = len(flow.pages)
    buf = io.BytesIO()
    with PdfPages(buf) as pdf:
        for n, (page, section) in enumerate(flow.pages, start=1):
            _furniture(page, doc, section, n, total)
            pdf.savefig(page)
    _merge_figures(buf.getvalue(), placements, path, doc.title)
    return total
