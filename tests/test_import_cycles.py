"""No import cycle in ``app/`` and ``cogmap_core/``: between modules, nor between sibling packages.

Read with ``ast`` (nothing is imported): every ``import`` counts, at module level, in functions
and under ``TYPE_CHECKING`` alike, so a cycle cannot hide behind a late import. Importing
``a.b.c`` counts as importing ``a`` and ``a.b`` too (their ``__init__`` runs first).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("app", "cogmap_core")


def _modules() -> dict[str, Path]:
    modules = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = path
    return modules


def _known(name: str, modules: dict[str, Path]) -> str | None:
    """The module of ours that ``name`` (a module, or a name in one) is, if any."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def _import_graph() -> tuple[dict[str, set[str]], dict[str, Path]]:
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets: list[str] = []
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                targets += [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parent = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    base = ".".join([*parent, *([node.module] if node.module else [])])
                targets += [base] + [f"{base}.{alias.name}" for alias in node.names]
        deps: set[str] = set()
        for target in targets:
            found = _known(target, modules)
            while found:  # the module and the packages above it, outside this module's own
                if found != name and not name.startswith(found + "."):
                    deps.add(found)
                found = found.rpartition(".")[0] or None
        graph[name] = deps
    return graph, modules


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one node (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    group.append(member)
                    if member == node:
                        break
                if len(group) > 1:
                    groups.append(sorted(group))
    return groups


def test_no_module_imports_itself_back():
    graph, _ = _import_graph()
    assert _cycles(graph) == []


def test_no_two_sibling_packages_import_each_other():
    graph, modules = _import_graph()

    def package(name: str) -> str:
        return name if modules[name].name == "__init__.py" else name.rpartition(".")[0]

    def related(a: str, b: str) -> bool:  # one holds the other: not siblings
        return a == b or a.startswith(b + ".") or b.startswith(a + ".")

    packages: dict[str, set[str]] = {}
    for name, deps in graph.items():
        here = package(name)
        packages.setdefault(here, set()).update(
            package(d) for d in deps if not related(here, package(d))
        )
    assert _cycles(packages) == []


def test_the_check_sees_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []
