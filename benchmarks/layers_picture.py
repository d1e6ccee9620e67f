"""The picture of gyrolab's layers: ``docs/img/layers.png``, drawn from the code.

The layers are ``tests/test_architecture.py``'s ``LAYERS`` (the rules the tests check), the
arrows the package-level imports its scanner finds in the source (every import form it
knows, lazy ones too). Each row is a layer, top to bottom as in docs/architecture.md; a
box is a package (or top-level module) with its lines of code; an arrow A → B says that
modules of A import modules of B, its width growing with the number of (module, module)
pairs. Arrows within a row are the ``SAME_LAYER`` pairs. Nothing of gyrolab is imported.

Usage: ``python benchmarks/layers_picture.py [--out docs/img/layers.png]``
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import sys
from collections import Counter
from pathlib import Path

os.environ.setdefault("MPLBACKEND", "Agg")

import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def _rules():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("arch", REPO / "tests" / "test_architecture.py")
    mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules["arch"] = mod  # its dataclasses look their module up
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


def package_edges(arch) -> Counter:  # type: ignore[no-untyped-def]
    """(importer package, imported package) -> number of distinct module pairs."""
    pairs = {
        (m, arch.target_module(i.target))
        for m, found in arch.IMPORTS.items()
        for i in found
        if arch.target_module(i.target) in arch.MODULES
    }
    return Counter((arch.unit(a), arch.unit(b)) for a, b in pairs if arch.unit(a) != arch.unit(b))


def package_lines(arch) -> Counter:  # type: ignore[no-untyped-def]
    return Counter(
        {
            u: sum(
                len(p.read_text(encoding="utf-8").splitlines())
                for m, p in arch.MODULES.items()
                if arch.unit(m) == u
            )
            for u in {arch.unit(m) for m in arch.MODULES}
        }
    )


FLOOR = "the floor"


def _order(layers: list[list[str]], edges: Counter) -> list[list[str]]:
    """Each row's boxes ordered by the mean position of their neighbours (a few
    barycentre sweeps down and up), so that fewer arrows cross."""
    rank = {u: float(i) for layer in layers for i, u in enumerate(layer)}
    nbrs: dict[str, list[str]] = {}
    for a, b in edges:
        nbrs.setdefault(a, []).append(b)
        nbrs.setdefault(b, []).append(a)
    for _ in range(4):
        for layer in [*layers[1:], *reversed(layers[:-1])]:
            for u in layer:
                near = [rank[v] - (len(layers[_row(layers, v)]) - 1) / 2 for v in nbrs.get(u, [])]
                rank[u] = sum(near) / len(near) if near else rank[u]
            layer.sort(key=lambda u: rank[u])
            for i, u in enumerate(layer):
                rank[u] = float(i)
    return layers


def _row(layers: list[list[str]], u: str) -> int:
    return next(i for i, layer in enumerate(layers) if u in layer)


def draw(out: Path) -> None:
    arch = _rules()
    floor = arch.LAYERS[-1]
    lines = package_lines(arch)
    edges: Counter = Counter()
    for (a, b), n in package_edges(arch).items():
        a, b = (FLOOR if a in floor else a), (FLOOR if b in floor else b)
        if a != b:
            edges[a, b] += n
    lines[FLOOR] = sum(lines[u] for u in floor)
    layers = _order([sorted(layer) for layer in arch.LAYERS[:-1]] + [[FLOOR]], edges)
    width = max(len(layer) for layer in layers)
    box_w, box_h, gap_x, gap_y = 1.7, 0.62, 0.45, 1.05
    pos: dict[str, tuple[float, float]] = {}
    for row, layer in enumerate(layers):
        x0 = (width - len(layer)) * (box_w + gap_x) / 2
        for i, u in enumerate(layer):
            pos[u] = (x0 + i * (box_w + gap_x) + box_w / 2, -row * gap_y)
    span = width * (box_w + gap_x) - gap_x
    fig, ax = plt.subplots(figsize=(span + 1.6, len(layers) * gap_y + 0.9))
    for row in range(len(layers)):
        y = -row * gap_y
        ax.add_patch(
            FancyBboxPatch(
                (-0.15, y - box_h / 2 - 0.12), span + 0.3, box_h + 0.24,
                boxstyle="round,pad=0.0,rounding_size=0.08",
                fc="#f3f5f8" if row % 2 else "#e9eef5", ec="none", zorder=0,
            )
        )  # fmt: skip
        ax.text(span + 0.3, y, f" layer {len(layers) - row}", va="center", fontsize=9, color="#555")
    for (a, b), n in sorted(edges.items()):
        (xa, ya), (xb, yb) = pos[a], pos[b]
        if ya == yb:  # a same-layer pair of the design: side to side, arched
            d = math.copysign(box_w / 2, xb - xa)
            start, end, style, color = (xa + d, ya), (xb - d, yb), "arc3,rad=-0.4", "#c0392b"
        else:
            start, end, style, color = (xa, ya - box_h / 2), (xb, yb + box_h / 2), "arc3", "#34495e"
        if b == FLOOR:  # the floor is wide: aim below the importer
            end = (min(max(xa, 0.3), span - 0.3), end[1])
        ax.add_patch(
            FancyArrowPatch(
                start, end, arrowstyle="-|>", mutation_scale=9, lw=0.4 + 0.5 * math.log2(n),
                color=color, alpha=0.5, connectionstyle=style, zorder=1,
            )
        )  # fmt: skip
    for u, (x, y) in pos.items():
        w = span if u == FLOOR else box_w
        cx = span / 2 if u == FLOOR else x
        ax.add_patch(
            FancyBboxPatch(
                (cx - w / 2, y - box_h / 2), w, box_h,
                boxstyle="round,pad=0.0,rounding_size=0.06", fc="white", ec="#2c3e50", lw=1.0,
                zorder=2,
            )
        )  # fmt: skip
        name = u
        if u == FLOOR:
            mods = sorted(floor - {"__init__"}) + ["__init__"]
            name = "the floor: " + "  ".join(f"{m}.py" for m in mods)
        fs = 9.5 if u != FLOOR else 8.0  # the floor's many modules on one line in its box
        ax.text(cx, y + 0.08, name, ha="center", va="center", fontsize=fs, weight="bold", zorder=3)
        ax.text(cx, y - 0.17, f"{lines[u]:,} lines", ha="center", va="center", fontsize=7.5,
                color="#555", zorder=3)  # fmt: skip
    ax.set_xlim(-0.3, span + 1.3)
    ax.set_ylim(-(len(layers) - 1) * gap_y - 0.6, 0.6)
    ax.set_axis_off()
    ax.set_title(
        "gyrolab's layers (tests/test_architecture.py): every import points down;\n"
        "red: the same-layer pairs of the design; width: module pairs",
        fontsize=10,
    )
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    print(f"wrote {out}: {len(arch.MODULES)} modules, {len(edges)} package arrows")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=REPO / "docs" / "img" / "layers.png")
    draw(ap.parse_args().out)


if __name__ == "__main__":
    main()
