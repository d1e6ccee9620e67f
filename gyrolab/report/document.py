"""The report as data: sections of figures, tables and text.

One :class:`Document` is rendered twice, to a self-contained HTML page (:mod:`.html`) and to
a PDF (:mod:`.pdf`), so the two always carry the same content.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from matplotlib.figure import Figure


@dataclass
class FigureBlock:
    """A figure; ``key`` is a stable id (the HTML element id, tests look for it)."""

    key: str
    title: str
    figure: Figure
    caption: str = ""


@dataclass
class TableBlock:
    """A table of already-formatted cells."""

    key: str
    title: str
    header: list[str]
    rows: list[list[str]]
    note: str = ""
    align_numbers: bool = True  # right-align numeric cells (off for field/value lists)


@dataclass
class TextBlock:
    """A paragraph of plain text (escaped when rendered)."""

    text: str
    kind: str = "p"  # "p" or "note" (highlighted)


Block = FigureBlock | TableBlock | TextBlock


@dataclass
class Section:
    key: str
    title: str
    blocks: list[Block] = field(default_factory=list)


@dataclass
class Document:
    """Title, a summary of (label, value) pairs shown first, then the sections."""

    title: str
    subtitle: str = ""
    summary: list[tuple[str, str]] = field(default_factory=list)
    sections: list[Section] = field(default_factory=list)
    status: str = ""  # run outcome (outcome.STATUSES): styles the header's outcome line
    running_header: str = ""  # on every PDF page: unit serial and run id

    def figures(self) -> list[FigureBlock]:
        return [b for s in self.sections for b in s.blocks if isinstance(b, FigureBlock)]

    def tables(self) -> list[TableBlock]:
        return [b for s in self.sections for b in s.blocks if isinstance(b, TableBlock)]
