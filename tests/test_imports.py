"""The packages' imports have no cycle: not at module level, not in a function body (a deferred
import), not under ``if TYPE_CHECKING:``. Read statically (``ast``), nothing is imported.

The module graph: an edge from module A to module B when A imports B anywhere in its text.

- ``import pkg.mod`` and ``from pkg.mod import name`` depend on ``pkg.mod``, not on the
  packages above it (Python runs ``pkg/__init__`` first, but what ``pkg.mod`` needs is
  ``pkg.mod``: counting the parent would make every module of ``trainer.tasks`` depend on all
  of the package's re-exports).
- ``from pkg import name`` depends on ``pkg.name`` when ``name`` is a submodule, else on
  ``pkg`` (its ``__init__``, where ``name`` is defined or re-exported).
- Only modules of the packages below count; the standard library and third parties do not.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable, Mapping
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("geomgrasp", "geomprep", "trainer")


def module_files(root: Path, packages: Iterable[str]) -> dict[str, Path]:
    """Every module of ``packages`` under ``root``: dotted name -> file (a package is its
    ``__init__.py``)."""
    found: dict[str, Path] = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


def _resolve(module: str, is_package: bool, level: int, target: str | None) -> str:
    """The absolute name of a relative import's base (``from ..a import b``: ``level`` 2)."""
    if level == 0:
        return target or ""
    parts = module.split(".")
    base = parts if is_package else parts[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join([*base, target] if target else base)


def imported_modules(module: str, is_package: bool, source: str, known: set[str]) -> set[str]:
    """The modules of ``known`` that ``source`` (the text of ``module``) imports, wherever the
    import statement is."""
    edges: set[str] = set()

    def nearest(name: str) -> str | None:
        # ``import pkg.mod.Thing`` is not valid Python, but a dotted name may name a module
        # that is not in ``known`` (e.g. a C extension): take its nearest known ancestor.
        while name and name not in known:
            name = name.rpartition(".")[0]
        return name or None

    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if (target := nearest(alias.name)) is not None:
                    edges.add(target)
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(module, is_package, node.level, node.module)
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                if sub in known:
                    edges.add(sub)
                elif (target := nearest(base)) is not None:
                    edges.add(target)
    edges.discard(module)
    return edges


def import_graph(root: Path = ROOT, packages: Iterable[str] = PACKAGES) -> dict[str, set[str]]:
    files = module_files(root, packages)
    known = set(files)
    return {
        name: imported_modules(name, path.name == "__init__.py", path.read_text(), known)
        for name, path in files.items()
    }


def cycles(graph: Mapping[str, Iterable[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative), each
    sorted, sorted by their first module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.get(start, ()))))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    parent = work[-1][0]
                    low[parent] = min(low[parent], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return sorted(found)


def _describe(component: list[str], graph: Mapping[str, Iterable[str]]) -> str:
    members = set(component)
    lines = [f"{len(component)} modules:"]
    for module in component:
        inside = sorted(set(graph[module]) & members)
        lines.append(f"  {module} -> {', '.join(inside)}")
    return "\n".join(lines)


def test_the_packages_have_no_import_cycle() -> None:
    graph = import_graph()
    found = cycles(graph)
    assert not found, "import cycles:\n" + "\n".join(_describe(c, graph) for c in found)


# ---------------------------------------------------------------------------------------------
# The finder itself


def test_cycles_finds_each_component_of_more_than_one_module() -> None:
    graph = {
        "a": {"b"}, "b": {"c"}, "c": {"a", "d"},  # a loop of three
        "d": {"e"}, "e": {"d"},  # a loop of two, reached from the first
        "f": {"a", "f"},  # a self edge and an edge into a loop: no component of its own
        "g": set(),
    }
    assert cycles(graph) == [["a", "b", "c"], ["d", "e"]]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []


def test_cycles_handles_a_long_chain_without_recursion() -> None:
    n = 5000
    chain = {f"m{i}": {f"m{i + 1}"} for i in range(n)}
    chain[f"m{n}"] = {"m0"}
    assert cycles(chain) == [sorted(chain)]


def test_deferred_and_type_checking_imports_are_edges(tmp_path: Path) -> None:
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from pkg.a import A\n")
    (pkg / "a.py").write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from pkg.b import B\n"
        "class A: ...\n"
    )
    (pkg / "b.py").write_text("def f():\n    from . import c\n    return c\n")
    (pkg / "c.py").write_text("import pkg.sub.d\nimport numpy\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "d.py").write_text("from .. import A\nfrom ..a import A as _A\n")
    graph = import_graph(tmp_path, ["pkg"])
    assert graph == {
        "pkg": {"pkg.a"},
        "pkg.a": {"pkg.b"},
        "pkg.b": {"pkg.c"},
        "pkg.c": {"pkg.sub.d"},
        "pkg.sub": set(),
        # ``from .. import A`` (a name of pkg/__init__) depends on pkg, ``from ..a`` on pkg.a.
        "pkg.sub.d": {"pkg", "pkg.a"},
    }
    assert cycles(graph) == [["pkg", "pkg.a", "pkg.b", "pkg.c", "pkg.sub.d"]]


def test_a_submodule_does_not_depend_on_its_package_reexports(tmp_path: Path) -> None:
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    # pkg/__init__ re-exports both; b uses a directly: no cycle through pkg.
    (pkg / "__init__.py").write_text("from pkg.a import A\nfrom pkg.b import B\n")
    (pkg / "a.py").write_text("class A: ...\n")
    (pkg / "b.py").write_text("from pkg.a import A\nfrom pkg import a\nclass B(A): ...\n")
    graph = import_graph(tmp_path, ["pkg"])
    assert graph == {"pkg": {"pkg.a", "pkg.b"}, "pkg.a": set(), "pkg.b": {"pkg.a"}}
    assert cycles(graph) == []
