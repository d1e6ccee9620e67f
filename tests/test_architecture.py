"""The layer rules of docs/architecture.md, checked on the source (``ast``, nothing imported).

An import of a gyrolab module is any of these, at module level or inside a function (a
lazy import counts like any other), and under ``if TYPE_CHECKING:`` too (a type is a tie):

- ``import gyrolab.x``, ``from gyrolab.x import y``, relative imports;
- ``importlib.import_module("gyrolab.x")`` or ``__import__("gyrolab.x")`` with a literal
  name, and a literal ``"gyrolab.x:name"`` reference (the form ``cli.HANDLERS`` and entry
  points use to name a function to import);
- an attribute chain through a bound gyrolab package or module: after ``import gyrolab``
  (or ``import gyrolab.a``, ``from gyrolab import sim``), ``gyrolab.x.y.f`` imports
  ``gyrolab.x.y`` (the longest prefix of the chain that is a module).

The rules:

(a) imports point downward only in the layer order (a module may import its own package
    freely; across packages of one layer only the pairs in SAME_LAYER); ``sim`` never
    imports ``acquisition`` or ``instruments``;
(b) nothing private (``_x``) crosses a module boundary: neither ``from m import _x``, nor
    ``m._x`` on a gyrolab module, nor ``obj._x`` where ``_x`` is a private attribute that
    classes of other modules define and none of this module's (their instances, or the
    classes themselves). ``self._x``, ``cls._x``, ``super()._x`` and the private
    attributes of a module's own classes are fine;
(c) no import cycle between packages;
(d) no import cycle between modules, inside one package either. A function-level (lazy)
    import that closes a circle is still a circle: it defers the tie, it does not remove
    it. The only exceptions are LAZY_BY_DESIGN, each edge lazy on every import and named,
    with its reason, in docs/architecture.md ("Lazy imports").

KNOWN holds the violations left in other helpers' areas while they are fixed, each with its
issue; the merge that lands a fix removes its entry (an entry that matches nothing fails).
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "gyrolab"
ARCHITECTURE_MD = ROOT.parent / "docs" / "architecture.md"

# Highest first. A package (or top-level module) of gyrolab belongs to one layer.
LAYERS: list[set[str]] = [
    {"cli", "__main__"},
    {"app"},
    {"report", "export", "batch", "convert"},
    {"compensation", "acquisition", "sim", "logs"},
    {"instruments"},
    {"record", "profiles", "catalogue"},
    {"numerics"},
    {"errors", "outputs", "progress", "tomlfile", "pt100", "framing", "clock", "sampling",
     "autopilot", "vectornav", "__init__"},
]
RANK = {unit: len(LAYERS) - i for i, layer in enumerate(LAYERS) for unit in layer}

# Imports across packages of one layer that are part of the design (importer, imported).
SAME_LAYER = {
    ("compensation", "logs"),  # compensate reads users' logs (ROS 2, ULog, DataFlash)
    ("compensation", "sim"),  # the oracle: the true drift of a simulated run (sim model)
    ("batch", "report"),  # batch runs report / compensate / discrepancy per recording
    ("__main__", "cli"),  # python -m gyrolab
    ("outputs", "errors"),  # the floor's modules share its error vocabulary
    ("tomlfile", "errors"),
    ("outputs", "__init__"),  # __version__ in the output marker
}

FORBIDDEN = {("sim", "acquisition"), ("sim", "instruments")}

# Circles closed only by function-level imports that the design keeps, each documented in
# docs/architecture.md under "Lazy imports": (importer, imported) -> why. None today.
LAZY_BY_DESIGN: dict[tuple[str, str], str] = {}

# Violations in other helpers' areas, being fixed in parallel: (importer module, imported
# module or name). The merge that lands the fix removes the entry.
KNOWN: set[tuple[str, str]] = set()


@dataclass(frozen=True)
class Import:
    importer: str  # dotted module name
    target: str  # dotted module name (or module.name for a name taken from a module)
    line: int
    lazy: bool = False  # inside a function (run when the function is called)


def modules() -> dict[str, Path]:
    """Every gyrolab module by dotted name."""
    out = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = path.relative_to(ROOT.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = modules()


def unit(module: str) -> str:
    """The package (or top-level module) of gyrolab that ``module`` belongs to."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _is_package(module: str) -> bool:
    path = MODULES.get(module)
    return path is not None and path.name == "__init__.py"


def _absolute(module: str, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module.split(".")[: len(module.split(".")) - node.level + _is_package(module)]
    return ".".join(base + ([node.module] if node.module else []))


def _walk(tree: ast.AST) -> Iterator[tuple[ast.AST, bool]]:
    """Every node with whether it lies inside a function (or lambda) body."""
    stack: list[tuple[ast.AST, bool]] = [(tree, False)]
    while stack:
        node, lazy = stack.pop()
        yield node, lazy
        inner = lazy or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        stack.extend((c, inner) for c in ast.iter_child_nodes(node))


_BY_NAME = re.compile(r"gyrolab(\.\w+)*")
_ENTRY_POINT = re.compile(r"(gyrolab(?:\.\w+)*):(\w+)")
_IMPORT_CALLS = {"import_module", "__import__"}


def _literal_import(node: ast.Call) -> str | None:
    """The literal gyrolab module an ``importlib.import_module`` / ``__import__`` call
    names, else None."""
    f = node.func
    name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
    if name not in _IMPORT_CALLS or not node.args:
        return None
    a = node.args[0]
    if isinstance(a, ast.Constant) and isinstance(a.value, str) and _BY_NAME.fullmatch(a.value):
        return a.value
    return None


def module_aliases(module: str, tree: ast.AST) -> dict[str, str]:
    """Local names bound to gyrolab modules (``import gyrolab.x as m``, ``from gyrolab
    import x``); ``import gyrolab.x.y`` binds ``gyrolab``, resolved through attributes."""
    names: dict[str, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "gyrolab":
                    names[a.asname or "gyrolab"] = a.name if a.asname else "gyrolab"
        elif isinstance(node, ast.ImportFrom):
            src = _absolute(module, node)
            for a in node.names:
                if f"{src}.{a.name}" in MODULES:
                    names[a.asname or a.name] = f"{src}.{a.name}"
    return names


def _dotted(node: ast.expr, aliases: dict[str, str]) -> str | None:
    if isinstance(node, ast.Name):
        return aliases.get(node.id)
    if isinstance(node, ast.Attribute):
        base = _dotted(node.value, aliases)
        return None if base is None else f"{base}.{node.attr}"
    return None


def _chain_targets(tree: ast.AST, aliases: dict[str, str]) -> Iterator[tuple[ast.Attribute, str]]:
    """The outermost attribute chains through a bound gyrolab module, with their dotted
    names (``gyrolab.x.y.f`` once, not also ``gyrolab.x``)."""
    inner: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and id(node) not in inner:
            dotted = _dotted(node, aliases)
            if dotted is None:
                continue
            v = node.value
            while isinstance(v, ast.Attribute):
                inner.add(id(v))
                v = v.value
            yield node, dotted


def imports(module: str, tree: ast.AST) -> Iterator[Import]:
    """The gyrolab imports of ``module`` (see the module docstring): modules, and
    ``module.name`` for a name taken from a module (``from m import name`` where
    ``m.name`` is not itself a module)."""
    for node, lazy in _walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "gyrolab":
                    yield Import(module, a.name, node.lineno, lazy)
        elif isinstance(node, ast.ImportFrom):
            src = _absolute(module, node)
            if src.split(".")[0] != "gyrolab":
                continue
            for a in node.names:
                yield Import(module, f"{src}.{a.name}", node.lineno, lazy)
        elif isinstance(node, ast.Call):
            name = _literal_import(node)
            if name is not None:
                yield Import(module, name, node.lineno, lazy)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            ep = _ENTRY_POINT.fullmatch(node.value)
            if ep is not None:
                yield Import(module, f"{ep.group(1)}.{ep.group(2)}", node.lineno, lazy)
    aliases = module_aliases(module, tree)
    lazy_at = {id(n): lazy for n, lazy in _walk(tree)}
    for node, dotted in _chain_targets(tree, aliases):
        tm = target_module(dotted)
        if tm in MODULES:  # the module, and the name taken from it (if the chain goes on)
            rest = dotted[len(tm) + 1 :].split(".")[0]
            yield Import(module, f"{tm}.{rest}" if rest else tm, node.lineno, lazy_at[id(node)])


def target_module(target: str) -> str:
    """The module an import target lives in (the target, or the module holding a name)."""
    while target not in MODULES and "." in target:
        target = target.rsplit(".", 1)[0]
    return target


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _self_attrs(fn: ast.AST) -> Iterator[str]:
    """Attributes a method sets on ``self``/``cls``: assignments, ``setattr(self, "_x",
    v)`` and ``object.__setattr__(self, "_x", v)`` (frozen dataclasses)."""
    for n in ast.walk(fn):
        targets: list[ast.expr] = []
        if isinstance(n, ast.Assign):
            targets = n.targets
        elif isinstance(n, (ast.AnnAssign, ast.AugAssign)):
            targets = [n.target]
        elif isinstance(n, ast.Call) and len(n.args) >= 2:
            f = n.func
            if (isinstance(f, ast.Name) and f.id == "setattr") or (
                isinstance(f, ast.Attribute) and f.attr == "__setattr__"
            ):
                obj, name = n.args[0], n.args[1]
                if isinstance(obj, ast.Name) and obj.id in ("self", "cls"):
                    if isinstance(name, ast.Constant) and isinstance(name.value, str):
                        yield name.value
        for t in targets:
            for x in ast.walk(t):
                if isinstance(x, ast.Attribute) and isinstance(x.value, ast.Name):
                    if x.value.id in ("self", "cls"):
                        yield x.attr


def private_attributes(tree: ast.AST) -> Iterator[tuple[str, str]]:
    """(class, name) of every private attribute the classes of a module define: methods,
    class attributes and fields in the class body, ``__slots__`` entries, and what its
    methods set on ``self``/``cls``."""
    for cls in ast.walk(tree):
        if not isinstance(cls, ast.ClassDef):
            continue
        names: set[str] = set()
        for b in cls.body:
            if isinstance(b, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names.add(b.name)
                if not isinstance(b, ast.ClassDef):
                    names.update(_self_attrs(b))
            elif isinstance(b, (ast.Assign, ast.AnnAssign)):
                targets = b.targets if isinstance(b, ast.Assign) else [b.target]
                names.update(t.id for t in targets if isinstance(t, ast.Name))
                if any(isinstance(t, ast.Name) and t.id == "__slots__" for t in targets):
                    for c in ast.walk(b.value) if b.value is not None else ():
                        if isinstance(c, ast.Constant) and isinstance(c.value, str):
                            names.add(c.value)
        for name in sorted(names):
            if _private(name):
                yield cls.name, name


def private_uses(
    module: str, tree: ast.AST, owners: dict[str, set[tuple[str, str]]] | None = None
) -> Iterator[Import]:
    """Private names used across modules: ``from m import _x``, ``m._x`` where ``m`` is
    another gyrolab module, and ``obj._x`` where ``_x`` is a private attribute only
    classes of other modules define (``owners``: name -> {(module, class)}; default: the
    whole package's). The target is ``module.Class._x`` of its (first) owner. Every use
    is reported, also the ones in KNOWN (the tests filter them)."""
    owners = OWNERS if owners is None else owners
    for imp in imports(module, tree):
        name = imp.target.rsplit(".", 1)[-1]
        if _private(name) and imp.target not in MODULES:
            if target_module(imp.target) != module:
                yield imp
    aliases = module_aliases(module, tree)
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute) or not _private(node.attr):
            continue
        if _dotted(node.value, aliases) is not None:
            continue  # on a module: an import of the name, checked above
        v = node.value
        if isinstance(v, ast.Name) and v.id in ("self", "cls"):
            continue
        if isinstance(v, ast.Call) and isinstance(v.func, ast.Name) and v.func.id == "super":
            continue
        own = owners.get(node.attr, set())
        if own and module not in {m for m, _ in own}:
            m, c = min(own)
            yield Import(module, f"{m}.{c}.{node.attr}", node.lineno)


TREES = {m: ast.parse(p.read_text(encoding="utf-8"), str(p)) for m, p in MODULES.items()}


def _owners(trees: dict[str, ast.AST]) -> dict[str, set[tuple[str, str]]]:
    out: dict[str, set[tuple[str, str]]] = {}
    for m, tree in trees.items():
        for cls, name in private_attributes(tree):
            out.setdefault(name, set()).add((m, cls))
    return out


OWNERS = _owners(TREES)
IMPORTS = {m: list(imports(m, tree)) for m, tree in TREES.items()}
PRIVATE = {m: list(private_uses(m, tree)) for m, tree in TREES.items()}


def test_every_package_has_a_layer() -> None:
    missing = sorted({unit(m) for m in MODULES} - set(RANK))
    assert not missing, f"packages without a layer (add them to LAYERS): {missing}"


def _layer_violations() -> list[str]:
    bad = []
    for m, found in IMPORTS.items():
        for imp in found:
            tm = target_module(imp.target)
            a, b = unit(m), unit(tm)
            if a == b:
                continue
            if (a, b) in FORBIDDEN:
                ok = False
            elif RANK[a] > RANK[b]:
                ok = True
            elif RANK[a] == RANK[b]:
                ok = (a, b) in SAME_LAYER
            else:
                ok = False
            if not ok and (m, tm) not in KNOWN:
                bad.append(f"{m}:{imp.line} imports {tm} ({a} -> {b})")
    return bad


def test_imports_point_down_the_layers() -> None:
    bad = _layer_violations()
    assert not bad, "imports against the layer order:\n" + "\n".join(bad)


def test_nothing_private_is_used_across_modules() -> None:
    bad = sorted(
        {
            f"{u.importer}:{u.line} uses {u.target}"
            for found in PRIVATE.values()
            for u in found
            if (u.importer, u.target) not in KNOWN
        }
    )
    assert not bad, "private names used across modules:\n" + "\n".join(bad)


def _cycles(graph: dict[str, set[str]]) -> list[str]:
    """One circle through each strongly connected part of ``graph`` (Tarjan), written
    ``a -> b -> … -> a``."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    parts: list[list[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = []
            while True:
                w = stack.pop()
                on.discard(w)
                part.append(w)
                if w == v:
                    break
            if len(part) > 1:
                parts.append(sorted(part))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    out = []
    for part in parts:  # a shortest way back to the first node, by breadth-first search
        inside, start = set(part), part[0]
        prev: dict[str, str] = {}
        frontier = [start]
        while start not in prev:
            nxt = []
            for v in frontier:
                for w in sorted(graph.get(v, set()) & inside):
                    if w not in prev:
                        prev[w] = v
                        nxt.append(w)
            frontier = nxt
        path = [start]
        while prev[path[-1]] != start:
            path.append(prev[path[-1]])
        out.append(" -> ".join([start, *reversed(path)]))
    return sorted(out)


def _module_graph() -> dict[str, set[str]]:
    """importer -> imported modules, every import (lazy ones too) but KNOWN and
    LAZY_BY_DESIGN edges."""
    graph: dict[str, set[str]] = {}
    for m, found in IMPORTS.items():
        for imp in found:
            tm = target_module(imp.target)
            if tm != m and tm in MODULES and (m, tm) not in KNOWN | LAZY_BY_DESIGN.keys():
                graph.setdefault(m, set()).add(tm)
    return graph


def test_no_import_cycle_between_packages() -> None:
    graph: dict[str, set[str]] = {}
    for m, targets in _module_graph().items():
        for tm in targets:
            if unit(m) != unit(tm):
                graph.setdefault(unit(m), set()).add(unit(tm))
    cycles = _cycles(graph)
    assert not cycles, "import cycles between packages:\n" + "\n".join(cycles)


def test_no_import_cycle_between_modules() -> None:
    """Inside a package too; a lazy import closing the circle still closes it."""
    cycles = _cycles(_module_graph())
    assert not cycles, "import cycles between modules:\n" + "\n".join(cycles)


def test_lazy_imports_by_design_are_lazy_and_documented() -> None:
    """A circle the design keeps is closed by function-level imports only, and
    docs/architecture.md names both modules and the reason under "Lazy imports"."""
    text = ARCHITECTURE_MD.read_text(encoding="utf-8")
    section = text.split("## Lazy imports", 1)[-1].split("\n## ", 1)[0] if LAZY_BY_DESIGN else ""
    for (a, b), why in LAZY_BY_DESIGN.items():
        edge = [i for i in IMPORTS[a] if target_module(i.target) == b]
        assert edge and all(i.lazy for i in edge), f"{a} -> {b} is not lazy on every import"
        for name in (a, b):
            assert f"`{name}`" in section, f"{name} ({why}) missing under 'Lazy imports'"


def test_the_allow_lists_hold_only_live_entries() -> None:
    """An entry whose violation is gone must go too (so KNOWN only shrinks), and every
    same-layer pair is one the code uses."""
    seen = set()
    for m, found in IMPORTS.items():
        for imp in found:
            seen.add((m, target_module(imp.target)))
            seen.add((m, imp.target))
        seen.update((u.importer, u.target) for u in PRIVATE[m])
    stale = sorted((KNOWN | LAZY_BY_DESIGN.keys()) - seen)
    assert not stale, f"allow-list entries with nothing to allow: {stale}"
    pairs = {(unit(a), unit(target_module(b))) for a, b in seen}
    unused = sorted(SAME_LAYER - pairs)
    assert not unused, f"SAME_LAYER pairs that no import uses: {unused}"


def test_the_checker_sees_every_form_of_import() -> None:
    """On a small module text: a function-level upward import, importlib and __import__
    with a literal name, a "module:function" reference, an attribute chain through
    ``import gyrolab`` and through a bound package, each with its laziness."""
    src = (
        "import importlib\n"
        "import gyrolab\n"
        "from gyrolab import sim\n"
        "HANDLER = 'gyrolab.app.report:report'\n"
        "def f():\n"
        "    from gyrolab.cli import main\n"
        "    importlib.import_module('gyrolab.report.data')\n"
        "    __import__('gyrolab.export.model_json')\n"
        "    importlib.import_module(f'gyrolab.{main}')  # not a literal: not seen\n"
        "    return gyrolab.compensation.fit.fit, sim.discrepancy.workflow.Workflow\n"
    )
    found = {(i.target, i.lazy) for i in imports("gyrolab.numerics.allan", ast.parse(src))}
    assert found == {
        ("gyrolab", False),
        ("gyrolab.sim", False),
        ("gyrolab.app.report.report", False),
        ("gyrolab.cli.main", True),
        ("gyrolab.report.data", True),
        ("gyrolab.export.model_json", True),
        ("gyrolab.compensation.fit.fit", True),
        ("gyrolab.sim.discrepancy.workflow.Workflow", True),
    }


def test_the_checker_sees_private_names_and_attributes() -> None:
    """A private name taken by ``from``, one used as a module attribute (also at the end
    of a longer chain), and another module's object's private attribute are found;
    ``self._x``, ``cls._x``, ``super()._x`` and the module's own class's are not."""
    other = ast.parse(
        "class Workflow:\n"
        "    _limit = 1\n"
        "    def __init__(self):\n"
        "        self._cache = {}\n"
        "        object.__setattr__(self, '_frozen', 1)\n"
        "    def _score(self): ...\n"
    )
    mine = ast.parse(
        "import gyrolab.sim.effects as fx\n"
        "from gyrolab.record import reader\n"
        "from gyrolab.sim.model import _private\n"
        "from gyrolab.x.workflow import Workflow\n"
        "class Own:\n"
        "    def __init__(self):\n"
        "        self._mine = 0\n"
        "    def f(self, other: 'Own', wf: Workflow):\n"
        "        self._cache = super()._cache\n"
        "        return (fx._play, reader._x.y, _private, other._mine, self._score,\n"
        "                wf._cache, Workflow._limit, wf.d._frozen, wf._score())\n"
    )
    owners = _owners({"gyrolab.x.workflow": other, "gyrolab.x.mine": mine})
    assert owners["_cache"] == {("gyrolab.x.workflow", "Workflow"), ("gyrolab.x.mine", "Own")}
    del owners["_cache"]  # set by both: ambiguous, this module's own name wins
    priv = {u.target for u in private_uses("gyrolab.x.mine", mine, owners)}
    assert priv == {
        "gyrolab.sim.model._private",
        "gyrolab.sim.effects._play",
        "gyrolab.record.reader._x",
        "gyrolab.x.workflow.Workflow._limit",
        "gyrolab.x.workflow.Workflow._frozen",
        "gyrolab.x.workflow.Workflow._score",
    }


def test_the_checker_sees_circles_inside_a_package() -> None:
    """Two modules of one package that import each other, one of them lazily, are a
    circle; the path is reported."""
    graph = {"p.a": {"p.b"}, "p.b": {"p.c"}, "p.c": {"p.a"}, "p.d": {"p.a"}}
    assert _cycles(graph) == ["p.a -> p.b -> p.c -> p.a"]
    assert _cycles({"p.a": {"p.b"}, "p.b": set()}) == []
    src = "def f():\n    from gyrolab.compensation.vmd import vmd\n"
    (imp,) = imports("gyrolab.compensation.vmd_triton", ast.parse(src))
    assert imp.lazy and target_module(imp.target) == "gyrolab.compensation.vmd"


def test_architecture_md_draws_these_layers() -> None:
    """docs/architecture.md's layer block names the packages of each layer, top down, as
    LAYERS does (its first code block; a line's names end at the first run of spaces)."""
    block = ARCHITECTURE_MD.read_text(encoding="utf-8").split("```", 2)[1]
    rows = [re.split(r"\s{2,}", line.strip())[0].split() for line in block.strip().splitlines()]
    assert [set(r) for r in rows] == LAYERS, rows


# ------------------------------------------------- one owner of the model directory

MODEL_DIR_OWNER = "gyrolab.compensation.model_dir"
#: The files a model directory consists of (gyrolab/compensation/model_dir.py).
MODEL_DIR_FILES = (
    "model.json",
    "arrays.npz",
    "metrics.json",
    "firmware.json",
    "results.json",
    "results.npz",
)
MODEL_DIR_NAMES = ("MODEL_JSON", "ARRAYS_NPZ", "METRICS_JSON", "FIRMWARE_JSON", "RESULTS_JSON")
#: A report directory has a metrics.json of its own (docs/report.md): written by the report,
#: read by the catalogue's indexing of reports.
OWN_FILES_ELSEWHERE = {
    ("gyrolab.report.commands", "metrics.json"),
    ("gyrolab.app.index_files", "metrics.json"),
    ("gyrolab.app.rebuild", "metrics.json"),
    ("gyrolab.app.register", "metrics.json"),
}


def _docstrings(tree: ast.AST) -> set[int]:
    out = set()
    for n in ast.walk(tree):
        body = getattr(n, "body", None)
        if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                out.add(id(body[0].value))
    return out


def model_dir_file_uses(module: str, tree: ast.AST) -> Iterator[str]:
    """Where ``module`` names a model directory's file: a string that is the file's name
    or a path ending in it (``".pt"``: a state dict's suffix), or the owner's constant
    for it (``ModelDir.MODEL_JSON``)."""
    docs = _docstrings(tree)
    for n in ast.walk(tree):
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs:
            for f in MODEL_DIR_FILES:
                named = n.value == f or n.value.endswith("/" + f)
                if named and (module, f) not in OWN_FILES_ELSEWHERE:
                    yield f"{module}:{n.lineno} names {f}"
            if n.value == ".pt":
                yield f"{module}:{n.lineno} names the .pt state dicts"
        elif isinstance(n, ast.Attribute) and n.attr in MODEL_DIR_NAMES:
            yield f"{module}:{n.lineno} uses {n.attr}"


def test_only_the_model_directory_owner_opens_its_files() -> None:
    """Issue 28: one owner of the model directory — every other module goes through
    ``ModelDir`` (guards, report/fleet, export, apply, compensate)."""
    bad = [
        u for m, tree in TREES.items() if m != MODEL_DIR_OWNER for u in model_dir_file_uses(m, tree)
    ]
    assert not bad, "model directory files named outside its owner:\n" + "\n".join(bad)
    src = (
        'def f(d):\n    """model.json"""\n'
        '    return d / "model.json", d.ARRAYS_NPZ, "x/metrics.json"\n'
    )
    found = list(model_dir_file_uses("gyrolab.report.x", ast.parse(src)))
    assert len(found) == 3, found  # the docstring is not a use
