"""The codebase's shape: no import cycle among the project's packages, modules of bounded size, and every
import inside a function says why it is there (heavy or optional)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("prl", "envs", "flows", "bench")
MAX_LINES = 600


def project_modules(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> file, for every module of ``PACKAGES`` under ``root``."""
    mods = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            name = ".".join(path.relative_to(root).with_suffix("").parts)
            mods[name.removesuffix(".__init__")] = path
    return mods


def import_graph(mods: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the project modules it imports anywhere in its file (functions included)."""

    def resolve(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for mod, path in mods.items():
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                deps.update(filter(None, (resolve(a.name) for a in node.names)))
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                for alias in node.names:  # ``from pkg import submodule`` imports the submodule
                    full = f"{node.module}.{alias.name}"
                    deps.add(resolve(full) if full in mods else resolve(node.module))
        graph[mod] = {d for d in deps if d and d != mod}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_cycle_through_a_function_level_import(tmp_path: Path) -> None:
    (tmp_path / "prl").mkdir()
    (tmp_path / "prl" / "__init__.py").write_text("")
    (tmp_path / "prl" / "a.py").write_text("from prl.b import x\n")
    (tmp_path / "prl" / "b.py").write_text("x = 1\ndef f():\n    from prl import a  # heavy\n")
    (tmp_path / "prl" / "c.py").write_text("import prl.a\n")
    graph = import_graph(project_modules(tmp_path))
    assert graph["prl.b"] == {"prl.a"} and graph["prl.c"] == {"prl.a"}
    assert cycles(graph) == [["prl.a", "prl.b"]]


def test_no_import_cycle_among_the_packages() -> None:
    assert cycles(import_graph(project_modules())) == []


def test_the_library_imports_neither_the_simulator_nor_prefect() -> None:
    """``prl`` is the pure library: ``envs`` and ``flows`` build on it, never the other way round."""
    banned = ("envs", "flows", "bench", "prefect", "prefect_dask", "sapien", "mani_skill")
    found = []
    for name, path in project_modules().items():
        if not name.startswith("prl"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            mods = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module] if isinstance(node, ast.ImportFrom) and node.module and not node.level else []
            found += [f"{name}: {m}" for m in mods if m.split(".")[0] in banned]
    assert found == []


def test_no_module_is_above_the_size_limit() -> None:
    sizes = {name: len(path.read_text().splitlines()) for name, path in project_modules().items()}
    assert {n: s for n, s in sizes.items() if s > MAX_LINES} == {}
    assert sizes["envs.executor"] <= 450 and sizes["prl.export"] <= 450


@pytest.mark.parametrize("pkg", PACKAGES)
def test_every_import_inside_a_function_says_why(pkg: str) -> None:
    """An import inside a function stays only where it is heavy or optional; its line (or the first line of
    its group, or the comment line just above the group) gives the reason after a ``#``."""
    silent = []
    for name, path in project_modules().items():
        if not name.startswith(pkg):
            continue
        lines = path.read_text().splitlines()
        for fn in ast.walk(ast.parse("\n".join(lines))):
            if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            body_imports = [n for n in fn.body if isinstance(n, ast.Import | ast.ImportFrom)]
            nested = [n for n in ast.walk(fn) if isinstance(n, ast.Import | ast.ImportFrom) and n not in body_imports]
            groups = _groups(body_imports) + [[n] for n in nested]
            for group in groups:
                said = any("#" in lines[n.lineno - 1] for n in group) or lines[group[0].lineno - 2].strip().startswith("#")
                if not said:
                    silent.append(f"{path.relative_to(ROOT)}:{group[0].lineno}")
    assert silent == []


def _groups(imports: list[ast.stmt]) -> list[list[ast.stmt]]:
    """Runs of imports on consecutive statement lines (one group shares one reason)."""
    groups: list[list[ast.stmt]] = []
    for node in imports:
        if groups and node.lineno <= groups[-1][-1].end_lineno + 2:
            groups[-1].append(node)
        else:
            groups.append([node])
    return groups
