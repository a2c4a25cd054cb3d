"""semmap's layering holds: pyproject.toml's import-linter contracts are kept, every top-level module has its place
in the layers, and no two of the top-level packages and modules import each other in a cycle."""

from __future__ import annotations

from pathlib import Path

import grimp
import pytest

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"
ROOT = "semmap"


@pytest.fixture(scope="module")
def contract() -> dict:
    """pyproject.toml's layers contract."""
    from importlinter.api import read_configuration

    return next(c for c in read_configuration(str(PYPROJECT))["contracts_options"] if c["type"] == "layers")


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return grimp.build_graph(ROOT, cache_dir=None)


def _lint(config: Path) -> int:
    """``lint-imports`` on ``config`` (its report printed, shown with a failure); 0 when every contract is kept.

    Calls import-linter's use case rather than its CLI function, which reconfigures logging and so silences the
    loggers of the tests that run after this one."""
    from importlinter import configuration
    from importlinter.application.use_cases import lint_imports

    configuration.configure()
    return 0 if lint_imports(config_filename=str(config), cache_dir=None, no_logo=True) else 1


def test_import_contracts_are_kept():
    assert _lint(PYPROJECT) == 0, "a contract in pyproject.toml is broken (the report above names the imports)"


def test_a_layer_order_the_code_contradicts_is_reported_broken(contract, tmp_path):
    upside_down = "".join(f"    {layer}\n" for layer in reversed(contract["layers"]))
    config = tmp_path / ".importlinter"
    config.write_text(f"[importlinter]\nroot_packages =\n    {ROOT}\n\n[importlinter:contract:upside-down]\n"
                      f"name = upside down\ntype = layers\nlayers =\n{upside_down}")
    assert _lint(config) == 1


def _top_level(module: str) -> str:
    return ".".join(module.split(".")[:2])


def test_every_top_level_module_has_its_layer(contract, graph):
    placed = {name.strip() for layer in contract["layers"]
              for name in layer.replace(":", "|").split("|")}
    modules = {_top_level(m) for m in graph.modules if m != ROOT and not m.endswith("__main__")}
    assert modules - placed == set(), "put each new top-level module on a layer in pyproject.toml"
    assert placed - modules == set(), "the layers name modules that do not exist"


def import_cycles(graph: grimp.ImportGraph, root: str = ROOT) -> list[list[str]]:
    """Groups of top-level packages/modules under ``root`` that import each other in a cycle (strongly connected
    components of the import graph squashed to the top level, Tarjan's algorithm)."""
    edges: dict[str, set[str]] = {}
    for module in graph.modules:
        if module == root:
            continue
        a = _top_level(module)
        edges.setdefault(a, set())
        for imported in graph.find_modules_directly_imported_by(module):
            b = _top_level(imported)
            if imported != root and b != a:
                edges[a].add(b)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

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
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                cycles.append(sorted(group))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return cycles


def test_no_import_cycles_between_top_level_packages_and_modules(graph):
    assert import_cycles(graph) == []


def test_the_cycle_finder_finds_a_cycle_through_submodules():
    g = grimp.ImportGraph()
    for importer, imported in [("pkg.a.x", "pkg.b"), ("pkg.b", "pkg.c.y"), ("pkg.c.y", "pkg.a"), ("pkg.d", "pkg.a")]:
        g.add_import(importer=importer, imported=imported)
    assert import_cycles(g, "pkg") == [["pkg.a", "pkg.b", "pkg.c"]]
