"""The codebase's shape: no import cycle among the project's packages, the layers (the pipeline, ``prl``, ``envs`` and
``flows``, never imports a benchmark or an experiment; no test imports either), modules of bounded size, and every
import inside a function says why it is there (heavy or optional)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("prl", "envs", "flows", "bench", "experiments")
PIPELINE = ("prl", "envs", "flows")
"""What the pipeline runs; ``bench`` (benchmarks of its defaults and targets) and ``experiments`` (one-off questions)
build on it and may import it, never the other way round, and ``bench`` does not import ``experiments``."""
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


def imported_names(path: Path) -> list[str]:
    """The absolute module names a file imports anywhere (functions included), and the constant names it hands to
    ``importlib.import_module``; ``from pkg import name`` gives ``pkg.name``."""
    names: list[str] = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names += [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None)) == \
                "import_module" and node.args and isinstance(node.args[0], ast.Constant) and \
                isinstance(node.args[0].value, str):
            names.append(node.args[0].value)
    return names


def imports_of_packages(paths: dict[str, Path], packages: tuple[str, ...]) -> list[str]:
    """``"<module>: <name>"`` for each import of one of ``packages`` by the files ``paths`` (name -> file)."""
    return [f"{mod}: {name}" for mod, path in sorted(paths.items()) for name in imported_names(path)
            if name.split(".")[0] in packages]


def modules_of_tests(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> file, for every Python file under ``root / "tests"``."""
    return {".".join(p.relative_to(root).with_suffix("").parts): p for p in sorted((root / "tests").rglob("*.py"))}


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


def test_the_import_finder_sees_imports_in_functions_and_by_name(tmp_path: Path) -> None:
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_a.py").write_text(
        "import prl.export\nfrom bench import bench_export\n"
        "def f():\n    from experiments.cores import main  # heavy\n    importlib.import_module('bench.x')\n")
    (tmp_path / "tests" / "test_b.py").write_text("from prl.export_compare import dataset_files\n")
    found = imports_of_packages(modules_of_tests(tmp_path), ("bench", "experiments"))
    assert found == ["tests.test_a: bench.bench_export", "tests.test_a: experiments.cores.main",
                     "tests.test_a: bench.x"]


def test_no_test_imports_a_benchmark_or_an_experiment() -> None:
    """A test checks the product: what one needs from ``bench`` or ``experiments`` belongs in ``prl`` or ``envs``."""
    assert imports_of_packages(modules_of_tests(), ("bench", "experiments")) == []


def test_the_pipeline_imports_no_benchmark_and_no_experiment() -> None:
    mods = project_modules()
    assert imports_of_packages({n: p for n, p in mods.items() if n.split(".")[0] in PIPELINE},
                               ("bench", "experiments")) == []
    assert imports_of_packages({n: p for n, p in mods.items() if n.split(".")[0] == "bench"}, ("experiments",)) == []


def test_the_library_imports_neither_the_simulator_nor_prefect() -> None:
    """``prl`` is the pure library: ``envs`` and ``flows`` build on it, never the other way round."""
    banned = ("envs", "flows", "bench", "experiments", "prefect", "prefect_dask", "sapien", "mani_skill")
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


DOC_WORDS = re.compile(r"\bsessions?\b", re.IGNORECASE)
"""Words the docs do not use: they speak of the project, not of the work sessions that made it (a dated archive
entry gives its date)."""
TEMPORARY_PATH = "/tmp/"
"""A path that exists only on the machine that ran something: the docs name outputs by placeholders instead."""


def doc_pages(root: Path = ROOT) -> list[Path]:
    """Every markdown page under ``docs/`` and the front door, ``README.md``."""
    return sorted((root / "docs").rglob("*.md")) + [root / "README.md"]


def doc_lines_to_fix(root: Path = ROOT) -> list[str]:
    """``"<page>:<line>"`` for each line of ``doc_pages`` that speaks of a session or names a temporary path."""
    found = []
    for path in doc_pages(root):
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if DOC_WORDS.search(line) or TEMPORARY_PATH in line:
                found.append(f"{path.relative_to(root).as_posix()}:{n}")
    return found


def pages_not_in_the_index(root: Path = ROOT) -> list[str]:
    """The markdown pages under ``docs/`` that the index, ``docs/README.md``, does not link (relative links, any
    anchor dropped), so that each page is found from it."""
    index = root / "docs" / "README.md"
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)\s]*)?\)", index.read_text())
    linked = {(index.parent / t).resolve() for t in targets if "://" not in t}
    pages = [p for p in sorted((root / "docs").rglob("*.md")) if p != index]
    return [p.relative_to(root).as_posix() for p in pages if p.resolve() not in linked]


def test_the_doc_checks_find_a_session_a_temporary_path_and_an_unlinked_page(tmp_path: Path) -> None:
    (tmp_path / "docs" / "guide").mkdir(parents=True)
    (tmp_path / "README.md").write_text("See [the docs](docs/README.md).\n")
    (tmp_path / "docs" / "README.md").write_text("- [a](guide/a.md#top)\n")
    (tmp_path / "docs" / "guide" / "a.md").write_text("Made in the eleventh Session.\npossession, sessional\n")
    (tmp_path / "docs" / "guide" / "b.md").write_text("Output in `/tmp/run3`; two sessions.\n")
    assert doc_lines_to_fix(tmp_path) == ["docs/guide/a.md:1", "docs/guide/b.md:1"]
    assert pages_not_in_the_index(tmp_path) == ["docs/guide/b.md"]


def test_the_docs_name_no_session_and_no_temporary_path() -> None:
    assert doc_lines_to_fix() == []


def test_the_docs_index_links_every_page() -> None:
    assert pages_not_in_the_index() == []
