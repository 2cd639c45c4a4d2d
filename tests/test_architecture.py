"""The house plan of STYLE.md and docs/architecture.md, checked on the source (issue 19).

Parses ``src/maglevid`` with :mod:`ast` (nothing is imported) and checks:

- no module imports another package's private (underscore) names;
- no import cycle between the modules of one package;
- no module below the CLI imports ``maglevid.cli`` (progress reporting is a
  callback passed in);
- module-level imports follow the layer order ``cli -> report -> diagnose ->
  identify -> simulate -> physics/control -> lti/data``; the exceptions are
  listed in ``LAYER_EXCEPTIONS``, each with its reason;
- no function or method is longer than :data:`MAX_FUNCTION_LINES` lines (STYLE.md:
  a long fit is a sequence of named steps, each under a screen).

A "package" is a first-level part of the library (``maglevid.diagnose``,
``maglevid.data``). The underscore modules at the top (``maglevid._validation``,
``maglevid._tables``, ``maglevid._plugins``) are the library's shared internals,
open to every package.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"

#: Layers, highest first: a module may import (at module level) from its own
#: layer's package or any lower layer. Packages not in STYLE.md's sentence are
#: placed where their imports put them (docs/architecture.md explains each).
LAYERS: dict[str, int] = {
    "maglevid.__main__": 10,
    "maglevid.cli": 9,
    "maglevid.api": 8,
    "maglevid.experiments": 8,
    "maglevid.fleet": 8,
    "maglevid.report": 7,
    "maglevid.plotting": 6,
    "maglevid.diagnose": 5,
    "maglevid.plants": 5,
    "maglevid.identify": 4,
    "maglevid.simulate": 3,
    "maglevid.physics": 2,
    "maglevid.control": 2,
    "maglevid.io": 2,
    "maglevid": 1,  # the package's namespace: re-exports data, lti, exceptions
    "maglevid.lti": 1,
    "maglevid.data": 1,
    "maglevid.jsonable": 1,
    "maglevid.parallel": 1,
    "maglevid.exceptions": 0,
    "maglevid._validation": 0,
    "maglevid._tables": 0,
    "maglevid._plugins": 0,
}

#: Module-level imports against the layer order that remain, with why.
#: (importer module, imported package) -> reason. Lazy imports inside
#: functions are not layer-checked (they are how a lower layer asks an upper
#: one for an optional service, e.g. io for a report's input table).
LAYER_EXCEPTIONS: dict[tuple[str, str], str] = {
    ("maglevid.identify.levitator", "maglevid.diagnose"): (
        "the one-coil fit needs the levitation segments that diagnose.quality finds; "
        "they move with the levitator's plant-kind module (issue 19, item 1)"
    ),
}


@dataclass(frozen=True)
class Import:
    importer: str  # module doing the import
    target: str  # full dotted name imported (module or module.name)
    module_level: bool
    line: int


def _module_name(path: Path) -> tuple[str, bool]:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    is_package = parts[-1] == "__init__"
    if is_package:
        parts = parts[:-1]
    return ".".join(parts), is_package


def _module_level_nodes(body: list[ast.stmt]) -> set[int]:
    """Imports run when the module is imported (not under ``if TYPE_CHECKING``)."""
    found: set[int] = set()
    for node in body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            found.add(id(node))
        elif isinstance(node, ast.If):
            if not (isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING"):
                found |= _module_level_nodes(node.body) | _module_level_nodes(node.orelse)
        elif isinstance(node, ast.Try):
            for block in (
                node.body,
                node.orelse,
                node.finalbody,
                *(h.body for h in node.handlers),
            ):
                found |= _module_level_nodes(block)
    return found


def _typing_only(tree: ast.Module) -> set[int]:
    """Imports under ``if TYPE_CHECKING:`` (annotations only; never run)."""
    return {
        id(n)
        for block in ast.walk(tree)
        if isinstance(block, ast.If)
        and isinstance(block.test, ast.Name)
        and block.test.id == "TYPE_CHECKING"
        for n in ast.walk(block)
        if isinstance(n, (ast.Import, ast.ImportFrom))
    }


def _imports() -> list[Import]:
    """Every import of a maglevid name that runs (module level or inside a function)."""
    out: list[Import] = []
    for path in sorted((SRC / "maglevid").rglob("*.py")):
        module, is_package = _module_name(path)
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        top = _module_level_nodes(tree.body)
        typing_only = _typing_only(tree)
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    package = module.split(".") if is_package else module.split(".")[:-1]
                    package = package[: len(package) - (node.level - 1)]
                    base = ".".join(package + ([base] if base else []))
                targets = [f"{base}.{a.name}" for a in node.names]
            else:
                continue
            for target in targets:
                if target == "maglevid" or target.startswith("maglevid."):
                    out.append(Import(module, target, id(node) in top, node.lineno))
    return out


IMPORTS = _imports()
MODULES = {_module_name(p)[0] for p in (SRC / "maglevid").rglob("*.py")}


def _as_module(target: str) -> str:
    """The module a dotted import target names (``a.b.name`` -> ``a.b``)."""
    while target not in MODULES and "." in target:
        target = target.rsplit(".", 1)[0]
    return target


def _package(module: str) -> str:
    """First-level part of the library: ``maglevid.diagnose.pipeline`` -> ``maglevid.diagnose``."""
    return ".".join(module.split(".")[:2])


def _is_private(segment: str) -> bool:
    return segment.startswith("_") and not segment.startswith("__")


def test_the_scan_sees_the_library():
    # A guard against a scan that finds nothing and so passes everything.
    assert len(MODULES) > 100
    assert sum(i.module_level for i in IMPORTS) > 300
    assert any(i.target == "maglevid.jsonable.to_jsonable" for i in IMPORTS)


def test_no_private_name_imported_across_packages():
    bad = []
    for imp in IMPORTS:
        segments = imp.target.split(".")
        first = next((k for k, s in enumerate(segments) if _is_private(s)), None)
        if first is None or first == 1:  # public, or a library-wide internal (maglevid._x)
            continue
        owner = _package(".".join(segments[:first]))
        if owner != _package(imp.importer):
            bad.append(f"{imp.importer}:{imp.line} imports {imp.target}")
    assert not bad, "private names of another package:\n" + "\n".join(bad)


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_between_modules_of_a_package():
    # Every import counts, also one inside a function: a cycle is a cycle even
    # when it only closes at run time (fleet.summary <-> fleet.worker did).
    # A package's __init__ re-exporting its modules is not part of a cycle.
    edges: dict[str, set[str]] = defaultdict(set)
    for imp in IMPORTS:
        target = _as_module(imp.target)
        same_package = _package(target) == _package(imp.importer)
        if same_package and target != imp.importer and target != _package(target):
            if imp.importer != _package(imp.importer):
                edges[imp.importer].add(target)
    assert _cycles(edges) == []


def test_nothing_below_the_cli_imports_it():
    bad = [
        f"{i.importer}:{i.line} imports {i.target}"
        for i in IMPORTS
        if _as_module(i.target).startswith("maglevid.cli")
        and not i.importer.startswith("maglevid.cli")
        and i.importer != "maglevid.__main__"  # `python -m maglevid` is the CLI's entry
    ]
    assert not bad, "imports of the CLI from below it:\n" + "\n".join(bad)


def test_every_package_has_a_layer():
    packages = {_package(m) for m in MODULES}
    assert packages <= set(LAYERS), sorted(packages - set(LAYERS))


def test_module_level_imports_follow_the_layer_order():
    bad, used = [], set()
    for imp in IMPORTS:
        if not imp.module_level:
            continue
        src, dst = _package(imp.importer), _package(_as_module(imp.target))
        if src == dst or LAYERS[dst] <= LAYERS[src]:
            continue
        key = (imp.importer, dst)
        if key in LAYER_EXCEPTIONS:
            used.add(key)
            continue
        bad.append(f"{imp.importer}:{imp.line} ({LAYERS[src]}) imports {imp.target} "
                   f"({LAYERS[dst]})")  # fmt: skip
    assert not bad, "imports against the layer order:\n" + "\n".join(bad)
    assert used == set(LAYER_EXCEPTIONS), (
        f"exceptions no longer needed: {set(LAYER_EXCEPTIONS) - used}"
    )


#: The longest function allowed, in lines from ``def`` to its last line (AST
#: ``end_lineno - lineno + 1``: decorators excluded, docstring included).
MAX_FUNCTION_LINES = 150

#: Functions allowed over the limit while being split (path under src/maglevid,
#: qualified name): none since issue 19's merge. A name here that is no longer
#: too long fails the test too, so the list cannot go stale.
TOO_LONG_BEING_SPLIT: frozenset[tuple[str, str]] = frozenset()


def _function_lengths(tree: ast.Module) -> list[tuple[str, int, int]]:
    """``(qualified name, first line, lines)`` of every function and method, nested ones too."""
    out: list[tuple[str, int, int]] = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = prefix + child.name
                end = child.end_lineno if child.end_lineno is not None else child.lineno
                out.append((name, child.lineno, end - child.lineno + 1))
                visit(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, prefix + child.name + ".")
            else:
                visit(child, prefix)

    visit(tree, "")
    return out


def _too_long(limit: int) -> dict[tuple[str, str], str]:
    found: dict[tuple[str, str], str] = {}
    for path in sorted((SRC / "maglevid").rglob("*.py")):
        rel = path.relative_to(SRC / "maglevid").as_posix()
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for name, line, length in _function_lengths(tree):
            if length > limit:
                found[(rel, name)] = f"{rel}:{line} {name} ({length} lines)"
    return found


def test_function_length_scan_measures_what_it_says():
    # A guard against a scan that misses functions: nested and method bodies are
    # found, lengths count from `def` to the last line, and the library has many.
    tree = ast.parse(
        "class A:\n    def f(self):\n        def g():\n            pass\n        return g\n"
    )
    assert _function_lengths(tree) == [("A.f", 2, 4), ("A.f.g", 3, 2)]
    assert len(_too_long(20)) > 100


def test_no_function_longer_than_150_lines():
    too_long = _too_long(MAX_FUNCTION_LINES)
    unexpected = [v for k, v in sorted(too_long.items()) if k not in TOO_LONG_BEING_SPLIT]
    assert not unexpected, (
        f"functions over {MAX_FUNCTION_LINES} lines (split them into named steps):\n"
        + "\n".join(unexpected)
    )
    stale = sorted(TOO_LONG_BEING_SPLIT - set(too_long))
    assert not stale, f"no longer over {MAX_FUNCTION_LINES} lines; remove from the list: {stale}"


#: The concrete plant kinds: one module each in maglevid/plants (issue 19, item 1).
KIND_MODULES = sorted(
    p.stem
    for p in (SRC / "maglevid" / "plants").glob("*.py")
    if p.stem not in ("__init__", "base")
)


def _kind_names() -> set[str]:
    """The ``name = "..."`` of each kind class in the kind modules (read with ast)."""
    names = set()
    for stem in KIND_MODULES:
        tree = ast.parse((SRC / "maglevid" / "plants" / f"{stem}.py").read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Assign)
                and any(isinstance(t, ast.Name) and t.id == "name" for t in node.targets)
                and isinstance(node.value, ast.Constant)
            ):
                names.add(node.value.value)
    return names


def _docstrings(tree: ast.Module) -> set[int]:
    nodes = [tree, *(n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.ClassDef)))]
    return {
        id(n.body[0].value)
        for n in nodes
        if n.body and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)
    }


def test_the_pipeline_names_no_plant_kind():
    # diagnose() runs the same stages for every kind and asks the kind object what
    # each stage does: no `kind == "levitator"` branch, no import of a kind's module
    # (maglevid.plants.amb, diagnose.levitator, physics.amb) at run time.
    assert KIND_MODULES == ["amb", "levitator", "mimo", "suspension"]
    names = _kind_names()
    assert names == {"amb-two-coil", "intersampled-suspension", "levitator", "mimo"}
    path = SRC / "maglevid" / "diagnose" / "pipeline.py"
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docs = _docstrings(tree)
    words = names | set(KIND_MODULES)
    bad = [
        f"pipeline.py:{n.lineno} says {n.value!r}"
        for n in ast.walk(tree)
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs
        if any(w in n.value.lower() for w in names | {"levitator", "suspension"})
    ]
    bad += [
        f"pipeline.py:{i.line} imports {i.target}"
        for i in IMPORTS
        if i.importer == "maglevid.diagnose.pipeline"
        and words & set(_as_module(i.target).split(".")[1:])
    ]
    assert not bad, "the pipeline names plant kinds:\n" + "\n".join(bad)
