"""Render a :class:`~gyrolab.report.document.Document` to one self-contained HTML page.

Figures are embedded as base64 PNG ``data:`` URIs and the style sheet is inline, so the
page has no external assets: it opens offline, can be mailed or archived as one file, and
prints (the print style sheet keeps figures and tables whole on a page). There is no
JavaScript at all.
"""

from __future__ import annotations

import base64
import html

from gyrolab.report.document import Document, FigureBlock, TableBlock, TextBlock
from gyrolab.report.figures import to_png

CSS = """
:root { --fg:#1b1b1b; --muted:#666; --line:#d0d0d0; --accent:#1f4e79; --bg:#fff; }
* { box-sizing: border-box; }
body { font: 15px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, "DejaVu Sans", sans-serif;
       color: var(--fg); background: var(--bg); margin: 0; }
main { max-width: 1060px; margin: 0 auto; padding: 24px 28px 60px; }
header.report { border-bottom: 3px solid var(--accent); margin-bottom: 18px; }
h1 { font-size: 26px; margin: 8px 0 2px; color: var(--accent); }
.subtitle { color: var(--muted); margin: 0 0 12px; }
h2 { font-size: 20px; margin: 34px 0 10px; padding-bottom: 4px;
     border-bottom: 1px solid var(--line); color: var(--accent); }
h3 { font-size: 15px; margin: 18px 0 6px; }
nav.toc ol { columns: 2; margin: 6px 0 0; padding-left: 20px; }
nav.toc a { color: var(--accent); text-decoration: none; }
dl.summary { display: grid; grid-template-columns: max-content 1fr; gap: 3px 16px;
             margin: 0 0 14px; }
dl.summary dt { color: var(--muted); }
dl.summary dd { margin: 0; font-weight: 600; }
dl.summary dd.st { padding: 1px 8px; border-left: 5px solid var(--line); }
dd.st-complete, dd.st-PASS { border-color: #2e7d32 !important; background: #edf7ee; }
dd.st-aborted, dd.st-interrupted { border-color: #e65100 !important; background: #fff3e0; }
dd.st-recovered, dd.st-incomplete, dd.st-FAIL { border-color: #c62828 !important;
                                                 background: #fdecea; }
figure { margin: 14px 0 22px; }
figure img { max-width: 100%; height: auto; display: block; border: 1px solid #eee; }
figcaption { color: var(--muted); font-size: 13px; margin-top: 4px; }
table { border-collapse: collapse; margin: 6px 0 4px; font-size: 13.5px; }
th, td { border: 1px solid var(--line); padding: 3px 9px; text-align: left; vertical-align: top; }
th { background: #f2f5f9; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
.table-wrap { overflow-x: auto; margin-bottom: 16px; }
p.note { background: #fff8e1; border-left: 4px solid #f0b400; padding: 6px 10px; }
.tnote { color: var(--muted); font-size: 12.5px; }
footer { margin-top: 40px; color: var(--muted); font-size: 12px; }
@media print {
  @page { size: A4; margin: 14mm; }
  body { font-size: 11pt; }
  main { max-width: none; padding: 0; }
  nav.toc { display: none; }
  h2 { break-before: page; }
  section:first-of-type h2 { break-before: auto; }
  figure, .table-wrap, tr { break-inside: avoid; }
  h2, h3 { break-after: avoid; }
  figure img { border: none; }
}
"""


def _e(text: object) -> str:
    return html.escape(str(text), quote=True)


def _is_num(cell: str) -> bool:
    try:
        float(cell.replace("×10", "e").replace("−", "-"))
    except ValueError:
        return False
    return True


def render_figure(block: FigureBlock, dpi: int = 110) -> str:
    """``<figure>`` with the PNG inline; ``alt`` is the title (for screen readers/tests)."""
    data = base64.b64encode(to_png(block.figure, dpi=dpi)).decode("ascii")
    cap = f"<figcaption>{_e(block.caption)}</figcaption>" if block.caption else ""
    return (
        f'<figure id="fig-{_e(block.key)}" class="figure">'
        f"<h3>{_e(block.title)}</h3>"
        f'<img alt="{_e(block.title)}" src="data:image/png;base64,{data}">{cap}</figure>'
    )


def render_table(block: TableBlock) -> str:
    head = "".join(f"<th>{_e(h)}</th>" for h in block.header)
    rows = []
    for row in block.rows:
        cells = "".join(
            f'<td class="num">{_e(c)}</td>'
            if block.align_numbers and _is_num(str(c))
            else f"<td>{_e(c)}</td>"
            for c in row
        )
        rows.append(f"<tr>{cells}</tr>")
    if not rows:
        rows.append(f'<tr><td colspan="{max(1, len(block.header))}">(none)</td></tr>')
    note = f'<p class="tnote">{_e(block.note)}</p>' if block.note else ""
    return (
        f'<div class="table-wrap" id="tab-{_e(block.key)}"><h3>{_e(block.title)}</h3>'
        f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"
        f"{note}</div>"
    )


def _dd(key: str, value: str, status: str) -> str:
    """A summary value; the outcome and verdict lines are coloured by what they say."""
    st = ""
    if key == "run outcome" and status:
        st = status
    elif key == "verdict" and value.split(" ")[0] in ("PASS", "FAIL"):
        st = value.split(" ")[0]
    cls = f' class="st st-{_e(st)}"' if st else ""
    return f"<dd{cls}>{_e(value)}</dd>"


def render(doc: Document, dpi: int = 110) -> str:
    """The whole page as one string."""
    parts: list[str] = []
    toc = "".join(f'<li><a href="#sec-{_e(s.key)}">{_e(s.title)}</a></li>' for s in doc.sections)
    summary = "".join(f"<dt>{_e(k)}</dt>{_dd(k, v, doc.status)}" for k, v in doc.summary)
    for sec in doc.sections:
        body: list[str] = []
        for b in sec.blocks:
            if isinstance(b, FigureBlock):
                body.append(render_figure(b, dpi))
            elif isinstance(b, TableBlock):
                body.append(render_table(b))
            elif isinstance(b, TextBlock):
                cls = ' class="note"' if b.kind == "note" else ""
                body.append(f"<p{cls}>{_e(b.text)}</p>")
        parts.append(
            f'<section id="sec-{_e(sec.key)}"><h2>{_e(sec.title)}</h2>{"".join(body)}</section>'
        )
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{_e(doc.title)}</title><style>{CSS}</style></head><body><main>"
        f'<header class="report"><h1>{_e(doc.title)}</h1>'
        f'<p class="subtitle">{_e(doc.subtitle)}</p>'
        f'<dl class="summary">{summary}</dl></header>'
        f'<nav class="toc"><strong>Contents</strong><ol>{toc}</ol></nav>'
        f"{''.join(parts)}"
        "<footer>Generated by gyrolab. This page is self-contained: every figure is embedded."
        "</footer></main></body></html>\n"
    )
