"""The PDF as a document: A4 pages, running header, page numbers, captions kept with
their tables, figures sized to the page (read back with pypdf; rendered with pdftoppm)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pypdf
import pytest

from gyrolab.report import figures as F
from gyrolab.report.document import Document, FigureBlock, Section, TableBlock, TextBlock
from gyrolab.report.pdf import write_pdf

A4_PT = (595.276, 841.890)


def _doc() -> Document:
    fig = F.compensated(np.arange(100.0), np.sin(np.arange(100.0) / 9), np.zeros(100))
    return Document(
        "Temperature test report — G-1",
        "sub",
        [("run outcome", "complete — profile complete"), ("unit under test", "G-1")],
        [
            Section("a", "Alpha", [TextBlock("intro " * 40), FigureBlock("c", "Comp", fig, "cap")]),
            Section(
                "b",
                "Beta",
                [
                    TextBlock("a note", "note"),
                    TableBlock("s", "Small", ["k", "v"], [["x", "1"], ["y", "2"]], "small note"),
                    TableBlock(
                        "t",
                        "Long",
                        ["key", "value"],
                        [[f"row{i:03d}", f"{i * 0.5}"] for i in range(120)],
                        "the end",
                    ),
                ],
            ),
        ],
        status="complete",
        running_header="G-1 · run.mcap · 2026-11-23T10:00:00+00:00",
    )


@pytest.fixture(scope="module")
def pdf(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int, Document]:
    doc = _doc()
    path = tmp_path_factory.mktemp("pdf") / "r.pdf"
    size = doc.figures()[0].figure.get_size_inches().copy()
    n = write_pdf(doc, path)
    # the figure is laid out on A4 for the PDF only: the HTML's figure is unchanged
    assert np.allclose(doc.figures()[0].figure.get_size_inches(), size)
    return path, n, doc


def test_every_page_is_a4_with_header_and_page_number(pdf) -> None:
    path, n, doc = pdf
    reader = pypdf.PdfReader(path)
    assert len(reader.pages) == n >= 4
    for k, page in enumerate(reader.pages, start=1):
        w, h = float(page.mediabox.width), float(page.mediabox.height)
        assert (w, h) == pytest.approx(A4_PT, abs=0.5), f"page {k}: {w} x {h} pt"
        text = page.extract_text()
        assert f"page {k} of {n}" in text
        assert "G-1 · run.mcap · 2026-11-23T10:00:00+00:00" in text


def test_table_captions_sit_above_their_rows_and_continue(pdf) -> None:
    path, n, _ = pdf
    texts = [p.extract_text() for p in pypdf.PdfReader(path).pages]
    (first,) = [i for i, t in enumerate(texts) if "Table 2. Long" in t and "continued" not in t]
    t = texts[first]
    # caption, then the header, then at least a few rows, on the same page
    assert t.index("Table 2. Long") < t.index("key") < t.index("row000") < t.index("row002")
    cont = [i for i, t in enumerate(texts) if "Table 2. Long (continued)" in t]
    assert cont and cont[0] == first + 1 and "row119" in texts[cont[-1]]
    assert "the end" in texts[cont[-1]]
    rows = [int(m) for t in texts for m in re.findall(r"row(\d{3})", t)]
    assert sorted(rows) == list(range(120))  # every row once, none lost at a page break
    # the small table and its note share the page with the note before it
    small = next(t for t in texts if "Table 1. Small" in t)
    assert "a note" in small and "small note" in small


def test_figure_has_its_number_title_and_caption_and_stays_vector(pdf) -> None:
    path, n, _ = pdf
    texts = [p.extract_text() for p in pypdf.PdfReader(path).pages]
    (k,) = [i for i, t in enumerate(texts) if "Figure 1. Comp" in t]
    assert "Alpha" in texts[k] and "cap" in texts[k]  # the heading travels with its figure
    # the figure is drawn as vector paths (its tick labels are text), not pasted as an image
    page = pypdf.PdfReader(path).pages[k]
    assert len(page.images) == 0 and "output (°/s)" in texts[k]


@pytest.mark.skipif(
    shutil.which("pdftoppm") is None,
    reason="pdftoppm not installed (apt-get install poppler-utils; .ci/run does)",
)
def test_pages_render_to_png_with_the_figure_across_the_page(pdf, tmp_path: Path) -> None:
    from PIL import Image

    path, n, _ = pdf
    subprocess.run(["pdftoppm", "-r", "40", "-png", str(path), str(tmp_path / "pg")], check=True)
    pngs = sorted(tmp_path.glob("pg-*.png"))
    assert len(pngs) == n
    for png in pngs:
        im = np.asarray(Image.open(png).convert("L"))
        assert im.shape[0] / im.shape[1] == pytest.approx(297 / 210, rel=0.01)
        assert (im < 200).mean() > 0.002  # not blank
    # the figure page: drawn content spans most of the page width
    texts = [p.extract_text() for p in pypdf.PdfReader(path).pages]
    k = next(i for i, t in enumerate(texts) if "Figure 1. Comp" in t)
    im = np.asarray(Image.open(pngs[k]).convert("L"))
    cols = np.flatnonzero((im[int(0.1 * im.shape[0]) : int(0.6 * im.shape[0])] < 200).any(axis=0))
    assert (cols[-1] - cols[0]) / im.shape[1] > 0.75


def _squash(text: str) -> str:
    """Text without whitespace: a wrapped cell reads the same as on one line."""
    return re.sub(r"\s+", "", text)


def pdf_misses(pdf_path: Path, tables: list[tuple[list[str], list[list[str]]]]) -> list[str]:
    """The cells (headers included) of ``tables`` whose full text is not in the PDF's text
    layer: a cell may wrap within its column, but no character of it may be lost."""
    text = _squash("".join(p.extract_text() for p in pypdf.PdfReader(pdf_path).pages))
    cells = {str(c) for header, rows in tables for c in [*header, *(c for r in rows for c in r)]}
    return sorted(c for c in cells if _squash(c) and _squash(c) not in text)


def test_no_table_cell_is_cut_wide_and_long_cells_wrap_or_split(tmp_path: Path) -> None:
    """What the old layout clipped ("bias stability…", "0.527–0.…", a coefficient table off
    the right edge) is all in the text layer: long cells wrap, a table too wide for the page
    is shown in parts of its columns with the first column repeated."""
    metric = [
        ["bias stability (°/h, std of 3.6 s)", "1.795", "0.527–0.612", "0:40:21.5 (2421.5 s)"],
        ["drift p-p of 100 s averages (°/s)", "0.001165", "—", "a rather long free-text cell " * 4],
        ["/a/very/long/path/" + "x" * 90 + "/run.mcap", "1", "2", "3"],
    ]
    wide_header = ["unit"] + [f"coefficient number {k} of the model (°/s/°C)" for k in range(12)]
    wide = [[f"SIM0-0{i}"] + [f"{0.1234567 * (i + k):.6g}" for k in range(12)] for i in range(4)]
    doc = Document(
        "Table layout",
        "sub",
        [],
        [
            Section(
                "t",
                "Tables",
                [
                    TableBlock("m", "Metrics", ["metric", "causal output", "range", "x"], metric),
                    TableBlock("w", "Coefficients per unit", wide_header, wide, "note under it"),
                ],
            )
        ],
    )
    path = tmp_path / "t.pdf"
    write_pdf(doc, path)
    assert pdf_misses(path, [(t.header, t.rows) for t in doc.tables()]) == []
    text = " ".join(p.extract_text() for p in pypdf.PdfReader(path).pages)
    assert "…" not in text  # nothing abbreviated
    parts = re.findall(r"Table 2\. Coefficients per unit \(columns (\d+)–(\d+) of 13\)", text)
    assert len(parts) >= 2 and parts[0][0] == "2" and parts[-1][1] == "13"
    assert text.count("SIM0-03") == len(parts)  # the first column in every part
