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


def _is_num(cell: str) -> bool:
    try:
        float(str(cell).replace("−", "-"))
    except ValueError:
        return False
    return True


def _numeric_column(rows: list[list[str]], i: int) -> bool:
    """Most of column ``i``'s filled cells are numbers: it is right-aligned."""
    filled = [str(r[i]) for r in rows if i < len(r) and str(r[i]).strip() not in ("", "—")]
    return bool(filled) and 2 * sum(_is_num(c) for c in filled) >= len(filled)


HEAD_W = 1.15  # bold header characters are ~15 % wider than the body's
LINE_STEP = 0.0107  # one more line of 7.5 pt text in a cell (linespacing 1.2)


def _token(text: str) -> int:
    """The longest run of characters a cell may not be broken in (a word, a number)."""
    return max((len(w) for w in str(text).split()), default=1)


def _least(header: list[str], rows: list[list[str]], budget: int) -> list[int]:
    """The narrowest each column may be: its longest word (wrapped cells break between
    words only), or a third of the page for a longer word (which then breaks)."""
    least = [int(_token(h) * HEAD_W) + 1 for h in header]
    for r in rows:
        for i, c in enumerate(r[: len(header)]):
            least[i] = max(least[i], _token(c))
    return [max(3, min(m, budget // 3)) for m in least]


def _widths(header: list[str], rows: list[list[str]], budget: int) -> list[int]:
    """Characters per column: each column's longest cell, the widest narrowed first until
    the table fits ``budget``, never below :func:`_least`."""
    natural = [int(len(str(h)) * HEAD_W) + 1 for h in header]
    for r in rows:
        for i, c in enumerate(r[: len(header)]):
            natural[i] = max(natural[i], len(str(c)))
    least = _least(header, rows, budget)
    chars = [max(n, m) for n, m in zip(natural, least, strict=True)]
    while sum(chars) > budget:
        wider = [k for k in range(len(chars)) if chars[k] > least[k]]
        if not wider:
            break  # the words do not fit: _column_groups splits such a table
        chars[max(wider, key=lambda k: chars[k])] -= 1  # the widest first: even columns
    return chars


def _pad(least: list[int], budget: int) -> int:
    """Characters between columns: ``PAD``, or 2 where that lets the columns fit."""
    return PAD if sum(least) + PAD * len(least) <= budget else 2


def _column_groups(block: TableBlock, budget: int) -> list[list[int]]:
    """The columns each part of a too-wide table shows: the first column (the row's name)
    in every part, the others shared out evenly among as few parts as fit side by side at
    their narrowest."""
    ncol = len(block.header)
    rows = [list(r) + [""] * (ncol - len(r)) for r in block.rows]
    least = _least(block.header, rows, budget)
    if sum(least) + _pad(least, budget) * ncol <= budget or ncol < 3:
        return [list(range(ncol))]

    def fits(cols: list[int]) -> bool:
        return sum(least[k] + 2 for k in cols) <= budget

    rest = list(range(1, ncol))
    for n in range(2, ncol):
        size = -(-len(rest) // n)  # ceil: parts of equal size, the last one smaller
        parts = [[0, *rest[i : i + size]] for i in range(0, len(rest), size)]
        if all(fits(p) for p in parts):
            return parts
    return [[0, c] for c in rest]


def _wrap(cell: str, n: int) -> str:
    """``cell`` on lines of at most ``n`` characters, broken between words (within a word
    only when the word alone is longer): every character of it is kept."""
    text = str(cell).replace("\n", " ")
    if len(text) <= n:
        return text
    return "\n".join(
        textwrap.wrap(text, n, break_on_hyphens=False, break_long_words=_token(text) > n)
    )


def _table(flow: _Flow, block: TableBlock, number: int) -> None:
    """Caption above, header, rows. Nothing is cut: a long cell wraps within its column; a
    table too wide for the page is shown in parts of its columns (the first column
    repeated, "columns a–b of n"); a table longer than the room left continues on the next
    page with its header repeated."""
    budget = int((RIGHT - LEFT) / CHAR_W)
    groups = _column_groups(block, budget)
    for part, cols in enumerate(groups):
        sub = TableBlock(
            block.key,
            block.title,
            [block.header[c] for c in cols],
            [[(list(r) + [""] * len(block.header))[c] for c in cols] for r in block.rows],
            block.note if part == len(groups) - 1 else "",
            block.align_numbers,
        )
        which = ""
        if len(groups) > 1:
            which = f" (columns {cols[1] + 1}–{cols[-1] + 1} of {len(block.header)})"
        _table_part(flow, sub, f"Table {number}. {block.title}{which}", budget)


def _table_part(flow: _Flow, block: TableBlock, caption: str, budget: int) -> None:
    """One table whose columns fit the page (:func:`_table`)."""
    ncol = max(1, len(block.header))
    rows = block.rows or [["(none)"] + [""] * (ncol - 1)]
    pad = _pad(_least(block.header, rows, budget), budget)
    chars = _widths(block.header, rows, budget - pad * ncol)
    xs = [LEFT]
    for c in chars[:-1]:
        xs.append(xs[-1] + (c + pad) * CHAR_W)
    width = sum((c + pad) * CHAR_W for c in chars)
    numeric = [block.align_numbers and _numeric_column(block.rows, i) for i in range(ncol)]

    def cells(row: list[str], head: bool) -> list[str]:
        w = [int(c / HEAD_W) if head else c for c in chars]
        return [_wrap(c, w[i]) for i, c in enumerate(list(row)[:ncol])]

    def height(wrapped: list[str]) -> float:
        return ROW_H + LINE_STEP * (max((c.count("\n") for c in wrapped), default=0))

    head = cells(block.header, True)
    body = [cells(r, False) for r in rows]
    note = textwrap.wrap(block.note, 115) if block.note else []
    start = 0
    while start < len(body):
        # caption + header + the first rows (up to 3) stay together
        first = sum(height(r) for r in body[start : start + 3])
        fig = flow.need(0.03 + height(head) + first)
        cont = " (continued)" if start else ""
        fig.text(LEFT, flow.y, f"{caption}{cont}", fontsize=9.5, weight="bold", va="top")
        flow.y -= 0.022
        room = flow.room() - height(head)
        chunk, used = [], 0.0
        while start + len(chunk) < len(body):
            h = height(body[start + len(chunk)])
            if chunk and used + h > room:
                break
            chunk.append(body[start + len(chunk)])
            used += h
        y = flow.y
        for r_i, row in enumerate([head, *chunk]):
            h = height(row)
            if r_i == 0:
                fig.add_artist(
                    Rectangle(
                        (LEFT - 0.004, y - h),
                        width,
                        h,
                        transform=fig.transFigure,
                        color="#e8eef5",
                        lw=0,
                    )
                )
            else:
                fig.add_artist(_hline(fig, LEFT - 0.004, LEFT - 0.004 + width, y))
            if not block.rows and r_i > 0:  # an empty table says so, across its width
                fig.text(xs[0], y - ROW_H / 2, "(none)", fontsize=7.5, va="center")
                y -= h
                continue
            for c_i, text in enumerate(row):
                right = numeric[c_i] and (r_i == 0 or _is_num(text))
                x = xs[c_i] + chars[c_i] * CHAR_W if right else xs[c_i]
                fig.text(
                    x,
                    y - (ROW_H - 0.0089) / 2,
                    text,
                    fontsize=7.5,
                    va="top",
                    ha="right" if right else "left",
                    weight="bold" if r_i == 0 else "normal",
                    linespacing=1.2,
                )
            y -= h
        flow.y = y
        start += len(chunk)
        if start >= len(body) and note:
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
