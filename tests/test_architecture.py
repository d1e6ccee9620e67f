"""The layer rules of docs/architecture.md, checked on the source (``ast``, nothing imported).

Every ``import`` of every gyrolab module counts, at module level and inside functions:

(a) imports point downward only in the layer order (a module may import its own package
    freely; across packages of one layer only the pairs in SAME_LAYER); ``sim`` never
    imports ``acquisition`` or ``instruments``;
(b) no private name (``_x``) is taken from another module, neither ``from m import _x``
    nor ``m._x`` on an imported gyrolab module;
(c) no import cycle between packages.

ALLOWED holds named exceptions while one is being fixed; it is empty.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "gyrolab"

# Highest first. A package (or top-level module) of gyrolab belongs to one layer.
LAYERS: list[set[str]] = [
    {"cli", "__main__"},
    {"app"},
    {"report", "export", "batch", "convert"},
    {"compensation", "acquisition", "sim", "logs"},
    {"instruments"},
    {"record", "profiles", "catalogue"},
    {"numerics"},
    {"errors", "outputs", "progress", "tomlfile", "pt100", "framing", "clock", "__init__"},
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

# Violations left in other helpers' areas (issue 13, worked on in parallel), by importer
# module and imported name; the merge removes each entry with its fix.
# Empty: every violation the parallel issue-13 work left has been removed. An entry is a
# named exception (importer, target) that the checks tolerate while it is being fixed.
ALLOWED: set[tuple[str, str]] = set()


@dataclass(frozen=True)
class Import:
    importer: str  # dotted module name
    target: str  # dotted module name (or module.name for a name taken from a module)
    line: int


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


def _absolute(module: str, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    is_pkg = MODULES[module].name == "__init__.py"
    base = module.split(".")[: len(module.split(".")) - node.level + (1 if is_pkg else 0)]
    return ".".join(base + ([node.module] if node.module else []))


def imports(module: str, tree: ast.AST) -> Iterator[Import]:
    """The gyrolab imports of ``module``: modules, and ``module.name`` for a name taken
    from a module (``from m import name`` where ``m.name`` is not itself a module)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "gyrolab":
                    yield Import(module, a.name, node.lineno)
        elif isinstance(node, ast.ImportFrom):
            src = _absolute(module, node)
            if src.split(".")[0] != "gyrolab":
                continue
            for a in node.names:
                yield Import(module, f"{src}.{a.name}", node.lineno)


def target_module(target: str) -> str:
    """The module an import target lives in (the target, or the module holding a name)."""
    while target not in MODULES and "." in target:
        target = target.rsplit(".", 1)[0]
    return target


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


def private_uses(module: str, tree: ast.AST) -> Iterator[Import]:
    """``m._x`` where ``m`` is another gyrolab module, and ``from m import _x``."""
    for imp in imports(module, tree):
        name = imp.target.rsplit(".", 1)[-1]
        if name.startswith("_") and not name.startswith("__") and imp.target not in MODULES:
            if target_module(imp.target) != module:
                yield imp
    aliases = module_aliases(module, tree)
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute) or not node.attr.startswith("_"):
            continue
        if node.attr.startswith("__"):
            continue
        base = _dotted(node.value, aliases)
        if base is not None and base in MODULES and base != module:
            yield Import(module, f"{base}.{node.attr}", node.lineno)


TREES = {m: ast.parse(p.read_text(encoding="utf-8"), str(p)) for m, p in MODULES.items()}


def test_every_package_has_a_layer() -> None:
    missing = sorted({unit(m) for m in MODULES} - set(RANK))
    assert not missing, f"packages without a layer (add them to LAYERS): {missing}"


def _layer_violations() -> list[str]:
    bad = []
    for m, tree in TREES.items():
        for imp in imports(m, tree):
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
            if not ok and (m, tm) not in ALLOWED:
                bad.append(f"{m}:{imp.line} imports {tm} ({a} -> {b})")
    return bad


def test_imports_point_down_the_layers() -> None:
    bad = _layer_violations()
    assert not bad, "imports against the layer order:\n" + "\n".join(bad)


def test_no_private_name_is_taken_across_modules() -> None:
    bad = [
        f"{u.importer}:{u.line} uses {u.target}"
        for m, tree in TREES.items()
        for u in private_uses(m, tree)
        if (u.importer, u.target) not in ALLOWED
    ]
    assert not bad, "private names used across modules:\n" + "\n".join(bad)


def test_no_import_cycle_between_packages() -> None:
    graph: dict[str, set[str]] = {}
    for m, tree in TREES.items():
        for imp in imports(m, tree):
            tm = target_module(imp.target)
            if unit(m) != unit(tm) and (m, tm) not in ALLOWED:
                graph.setdefault(unit(m), set()).add(unit(tm))
    cycles = []
    state: dict[str, int] = {}  # 1: on the path, 2: done

    def visit(u: str, path: list[str]) -> None:
        state[u] = 1
        for v in sorted(graph.get(u, ())):
            if state.get(v) == 1:
                cycles.append(" -> ".join([*path[path.index(v) :], v]))
            elif v not in state:
                visit(v, [*path, v])
        state[u] = 2

    for u in sorted(graph):
        if u not in state:
            visit(u, [u])
    assert not cycles, "import cycles between packages:\n" + "\n".join(cycles)


def test_the_allow_list_holds_only_live_entries() -> None:
    """An entry whose violation is gone must go too (so the list only shrinks), and every
    same-layer pair is one the code uses."""
    seen = set()
    for m, tree in TREES.items():
        for imp in imports(m, tree):
            seen.add((m, target_module(imp.target)))
            seen.add((m, imp.target))
        seen.update((u.importer, u.target) for u in private_uses(m, tree))
    stale = sorted(ALLOWED - seen)
    assert not stale, f"allow-list entries with nothing to allow: {stale}"
    pairs = {(unit(a), unit(target_module(b))) for a, b in seen}
    unused = sorted(SAME_LAYER - pairs)
    assert not unused, f"SAME_LAYER pairs that no import uses: {unused}"


def test_the_checker_sees_function_level_and_attribute_imports() -> None:
    """The checks themselves, on a small module text: a function-level upward import, a
    private name taken by ``from``, and one used as a module attribute are all found."""
    src = (
        "import gyrolab.sim.effects as fx\n"
        "from gyrolab.record import reader\n"
        "def f():\n"
        "    from gyrolab.cli import main\n"
        "    from gyrolab.sim.model import _private\n"
        "    return fx._play, reader._x, main, _private\n"
    )
    tree = ast.parse(src)
    mod = "gyrolab.numerics.allan"
    targets = {target_module(i.target) for i in imports(mod, tree)}
    assert {"gyrolab.cli", "gyrolab.sim.model", "gyrolab.record.reader"} <= targets
    priv = {u.target for u in private_uses(mod, tree)}
    assert priv == {
        "gyrolab.sim.model._private",
        "gyrolab.sim.effects._play",
        "gyrolab.record.reader._x",
    }


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
