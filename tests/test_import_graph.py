"""The house has no import circle (issue 29): in the SDK, the service, the worker and the
benchmarks, no module imports, at any depth and by any import (top level, inside a
function, or only for type checking), a module that imports it back. A circle means a
shared piece has no home of its own (qei's options once lived in qei, which imported
the modules that needed them). And the one-way rules: the service and the worker never
import each other, and the SDK imports neither; the tests and the benchmarks never import
each other, at any depth (what both need is the SDK's process harness,
``adclient.testing``), and no package imports either of them."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {
    "adclient": ROOT / "client",
    "adservice": ROOT / "service",
    "adworker": ROOT / "workers",
    "bench": ROOT,
    "tests": ROOT,
}


def modules() -> dict[str, Path]:
    """Every module of the five packages by dotted name (a package by its own name)."""
    found = {}
    for package, base in PACKAGES.items():
        for path in (base / package).rglob("*.py"):
            parts = list(path.relative_to(base).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


def imports(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The known modules ``name`` imports: ``from a.b import c`` is ``a.b.c`` where that
    is a module, else ``a.b`` (its nearest known ancestor); ``importlib.import_module``
    and ``__import__`` of a literal name count too."""

    def nearest(dotted: str) -> str | None:
        while dotted and dotted not in known:
            dotted = dotted.rpartition(".")[0]
        return dotted or None

    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str | None] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found.update(nearest(alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([node.module] if node.module else []))
            for alias in node.names:
                full = f"{base}.{alias.name}"
                found.add(full if full in known else nearest(base))
        elif (
            isinstance(node, ast.Call)
            and ast.unparse(node.func) in ("importlib.import_module", "import_module", "__import__")
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            found.add(nearest(node.args[0].value))
    found.discard(None)
    found.discard(name)
    return {module for module in found if module is not None}


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The graph's strongly connected components of more than one module (Tarjan's)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(start: str) -> None:
        # iterative, so a deep chain of imports cannot exhaust the recursion limit
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, edges = work[-1]
            for target in edges:
                if target not in index:
                    index[target] = low[target] = len(index)
                    stack.append(target)
                    on_stack.add(target)
                    work.append((target, iter(sorted(graph[target]))))
                    break
                if target in on_stack:
                    low[node] = min(low[node], index[target])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
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

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    known = modules()
    return {name: imports(name, path, known) for name, path in known.items()}


def test_the_finder_sees_a_circle_and_a_chain_apart() -> None:
    chain = {"a": {"b"}, "b": {"c"}, "c": set()}
    assert circles(chain) == []
    assert circles({**chain, "c": {"a"}}) == [["a", "b", "c"]]
    assert circles({"a": {"b"}, "b": {"a"}, "c": {"d"}, "d": {"c"}}) == [["a", "b"], ["c", "d"]]


def test_the_graph_sees_lazy_and_type_checking_imports(graph: dict[str, set[str]]) -> None:
    """The module that once closed a circle only for the type checker is seen."""
    assert "adclient.calls" in graph["adclient.study"]  # under TYPE_CHECKING
    assert "adservice.proposers.gpfit" in graph["adservice.proposers.qei"]  # in a function


def test_no_module_imports_one_that_imports_it_back(graph: dict[str, set[str]]) -> None:
    found = circles(graph)
    assert not found, "import circles: " + "; ".join(" <-> ".join(c) for c in found)


def test_the_service_and_the_worker_never_import_each_other(graph: dict[str, set[str]]) -> None:
    def crossing(source: str, targets: tuple[str, ...]) -> list[str]:
        return sorted(
            f"{name} -> {module}"
            for name, imported in graph.items()
            if name.split(".")[0] == source
            for module in imported
            if module.split(".")[0] in targets
        )

    assert crossing("adservice", ("adworker", "bench")) == []
    assert crossing("adworker", ("adservice", "bench")) == []
    assert crossing("adclient", ("adservice", "adworker", "bench")) == []


def reachable(graph: dict[str, set[str]], start: str) -> set[str]:
    """Every module ``start`` imports, directly or through others."""
    seen: set[str] = set()
    work = [start]
    while work:
        for module in graph[work.pop()] - seen:
            seen.add(module)
            work.append(module)
    return seen


def crossings(graph: dict[str, set[str]], source: str, target: str) -> list[str]:
    """Each module of package ``source`` that reaches package ``target``, with one module
    of ``target`` it reaches."""
    found = []
    for name in sorted(graph):
        if name.split(".")[0] == source:
            reached = sorted(m for m in reachable(graph, name) if m.split(".")[0] == target)
            if reached:
                found.append(f"{name} -> {reached[0]}")
    return found


def test_the_checks_see_every_import_form_and_a_crossing_at_depth(tmp_path: Path) -> None:
    """A crossing through a module between, by each import form the house uses."""
    known = {
        "tests.a": tmp_path / "a.py",
        "tests.b": tmp_path / "b.py",
        "bench": tmp_path / "__init__.py",
        "bench.load": tmp_path / "load.py",
        "bench.slow": tmp_path / "slow.py",
    }
    known["tests.a"].write_text(
        "def f():\n    import importlib\n    return importlib.import_module('bench.load')\n"
    )
    known["tests.b"].write_text("from bench import slow\n")
    known["bench"].write_text("")
    known["bench.load"].write_text("from . import slow\n")
    known["bench.slow"].write_text("import tests.b as b\n")
    graph = {name: imports(name, path, known) for name, path in known.items()}
    assert graph["tests.a"] == {"bench.load"} and graph["bench.load"] == {"bench.slow"}
    assert crossings(graph, "bench", "tests") == ["bench.load -> tests.b", "bench.slow -> tests.b"]
    assert crossings(graph, "tests", "bench")[0] == "tests.a -> bench.load"


def test_the_tests_and_the_benchmarks_never_import_each_other(graph: dict[str, set[str]]) -> None:
    assert len([name for name in graph if name.startswith("tests.")]) > 100
    assert crossings(graph, "tests", "bench") == []
    assert crossings(graph, "bench", "tests") == []
    for package in ("adclient", "adservice", "adworker"):
        assert crossings(graph, package, "tests") == []
