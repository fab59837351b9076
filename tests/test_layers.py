"""The package's layers as issue 52 fixed them: imports read from the source (top-level,
inside functions and under ``TYPE_CHECKING`` alike), so a lazy import counts as much as
any other.

* no cycle between modules, lazy imports included;
* arrows that must not exist (a lower layer reaching up): plants -> effects or the task's
  feasibility, config -> controllers, the loop -> studies, mjx -> sweep;
* no module imports a private name (``_x``) of another package;
* at most 16 entries at the top level of ``tspend/``, at most 25 ``type: ignore``;
* no function longer than 60 lines in ``tspend/controllers/`` (``mpsc.py`` is the safety
  filter issue's) nor in the gym environment nor in ``tspend/mjx/`` (``control.py`` is
  the law issue's).

Each check runs a small reader of ``ast`` over the files; the reader is itself tested on
made-up sources, so a check that could never fail would show here.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import tspend

PACKAGE = Path(tspend.__file__).resolve().parent
ROOT = PACKAGE.name

#: (importer prefix, imported prefix): arrows that climb back up a layer
FORBIDDEN = (("tspend.plants", "tspend.loop.effects"), ("tspend.plants", "tspend.task.feasibility"),
             ("tspend.config", "tspend.controllers"), ("tspend.loop", "tspend.studies"),
             ("tspend.mjx", "tspend.sweep"))
#: at most this many entries at the top level of tspend/ (files and folders)
MAX_TOP_LEVEL = 16
#: at most this many ``type: ignore`` comments in the package
MAX_TYPE_IGNORES = 25
#: the longest function or constructor allowed in the folders :data:`SHORT` names, lines
MAX_FUNCTION_LINES = 60
#: (folder or file under tspend/, files left out): where every function is short
SHORT = (("controllers", ("mpsc.py",)), ("gym", ()), ("mjx", ("control.py",)))


def modules_of(sources: dict[str, str]) -> dict[str, tuple[str, bool]]:
    """Module name -> (its source, whether it is a package's ``__init__``), from
    ``{relative path: source}``."""
    out = {}
    for path, text in sources.items():
        parts = path[:-3].split("/")
        init = parts[-1] == "__init__"
        name = ".".join(parts[:-1] if init else parts)
        out[name] = (text, init)
    return out


def imports_of(modules: dict[str, tuple[str, bool]]) -> list[tuple[str, str, str]]:
    """Every import of a module of the package: ``(importer, imported module, name)``,
    ``name`` the imported name ("" for ``import x``), wherever the statement stands."""
    def resolve(dotted: str) -> str | None:
        while dotted and dotted not in modules:
            dotted = dotted.rpartition(".")[0]
        return dotted or None

    out = []
    for name, (text, init) in modules.items():
        base = name if init else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.Import):
                pairs = [(a.name, "") for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    b = base
                    for _ in range(node.level - 1):
                        b = b.rpartition(".")[0]
                    source = f"{b}.{node.module}" if node.module else b
                else:
                    source = node.module or ""
                # ``from pkg import module`` imports the module; ``from m import name`` m
                pairs = [(f"{source}.{a.name}" if resolve(f"{source}.{a.name}") ==
                          f"{source}.{a.name}" else source, a.name) for a in node.names]
            else:
                continue
            for dotted, imported in pairs:
                target = resolve(dotted) if dotted.split(".")[0] == name.split(".")[0] else None
                if target and target != name:
                    out.append((name, target, imported))
    return out


def cycles(edges: list[tuple[str, str, str]], facade: str) -> list[list[str]]:
    """Groups of modules that import each other (Tarjan), leaving out imports of the
    package's facade ``facade`` and a package's ``__init__`` with its own children."""
    graph: dict[str, set[str]] = {}
    for a, b, _ in edges:
        if b == facade or b.startswith(a + ".") or a.startswith(b + "."):
            continue
        graph.setdefault(a, set()).add(b)
        graph.setdefault(b, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def private_imports(edges: list[tuple[str, str, str]]) -> list[tuple[str, str, str]]:
    """Imports of a ``_private`` name from a module of another package."""
    def package(module: str) -> str:
        return module.rpartition(".")[0]

    return [(a, b, n) for a, b, n in edges
            if n.startswith("_") and not n.startswith("__") and package(a) != package(b)
            and not b.startswith(a + ".")]


def _package_sources() -> dict[str, str]:
    return {p.relative_to(PACKAGE.parent).as_posix(): p.read_text(encoding="utf-8")
            for p in sorted(PACKAGE.rglob("*.py")) if "__pycache__" not in p.parts}


@functools.lru_cache(maxsize=1)
def _edges() -> list[tuple[str, str, str]]:
    return imports_of(modules_of(_package_sources()))


# -- the reader on made-up sources: each check can fail ------------------------------------
MADE_UP = {
    "p/__init__.py": "",
    "p/low.py": "def f():\n    from p.high import g  # lazy, and still an arrow\n",
    "p/high.py": "from p.low import f\nfrom p.other.mod import _hidden\n",
    "p/other/__init__.py": "",
    "p/other/mod.py": "_hidden = 1\n",
}


def test_the_reader_finds_a_lazy_cycle_and_a_private_import():
    edges = imports_of(modules_of(MADE_UP))
    assert ("p.low", "p.high", "g") in edges
    assert cycles(edges, "p") == [["p.high", "p.low"]]
    assert private_imports(edges) == [("p.high", "p.other.mod", "_hidden")]
    without = dict(MADE_UP, **{"p/low.py": "def f():\n    return 1\n"})
    assert cycles(imports_of(modules_of(without)), "p") == []


# -- the package --------------------------------------------------------------------------
def test_no_import_cycle_lazy_imports_included():
    assert cycles(_edges(), ROOT) == []


def test_no_arrow_climbs_back_up():
    climbing = [(a, b) for a, b, _ in _edges() for low, high in FORBIDDEN
                if (a == low or a.startswith(low + ".")) and (b == high or b.startswith(high + "."))]
    assert climbing == []


def test_sweep_and_mjx_do_not_import_each_other_both_ways():
    edges = _edges()
    arrows = {(a.split(".")[1], b.split(".")[1]) for a, b, _ in edges
              if a.count(".") and b.count(".")}
    assert not {("sweep", "mjx"), ("mjx", "sweep")} <= arrows


def test_no_private_name_of_another_package_is_imported():
    assert private_imports(_edges()) == []


def test_top_level_and_type_ignores_stay_bounded():
    entries = sorted(p.name for p in PACKAGE.iterdir() if p.name != "__pycache__")
    assert len(entries) <= MAX_TOP_LEVEL, entries
    ignores = sum(text.count("type: ignore") for text in _package_sources().values())
    assert ignores <= MAX_TYPE_IGNORES


def _long_functions(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return [f"{path.name}:{n.lineno} {n.name} ({n.end_lineno - n.lineno + 1} lines)"
            for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))
            and n.end_lineno - n.lineno + 1 > MAX_FUNCTION_LINES]


def test_functions_are_short_where_design_is_split_from_running():
    long = []
    for where, left_out in SHORT:
        place = PACKAGE / where
        files = [place] if place.is_file() else sorted(place.rglob("*.py"))
        for path in files:
            if path.name not in left_out:
                long += _long_functions(path)
    assert long == []
