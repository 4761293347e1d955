"""``prl.version.outcome_version``: the code version of what decides an LN point's outcome on one task, on a copy
of the file layout in a temporary tree and against the imports of the listed modules."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from prl import version
from prl.config import known_tasks
from prl.constants import REPO_ROOT, TASKS
from prl.version import OUTCOME_SHARED_FILES, outcome_files, outcome_version

LEFT_OUT = {"prl/config.py", "envs/tasks/grasp_probe.py"}
"""Modules the listed files import that do not decide an outcome (see ``OUTCOME_SHARED_FILES``' docstring)."""


@pytest.fixture()
def tree(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A checkout's layout with placeholder contents, which ``prl.version`` takes for the repository."""
    for rel in [*OUTCOME_SHARED_FILES, *(f"envs/tasks/{t}.py" for t in TASKS), "assets/plb.yaml",
                "assets/hand/prl_hand.urdf", "README.md", "docs/results.md", "flows/ablation.py",
                "envs/synthesis.py", "tests/prl/test_x.py"]:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(f"# {rel}\n")
    monkeypatch.setattr(version, "REPO_ROOT", tmp_path)
    return tmp_path


def versions() -> dict[str, str]:
    return {t: outcome_version(t) for t in TASKS}


def test_a_task_module_changes_its_own_version_only(tree: Path) -> None:
    before = versions()
    assert len(set(before.values())) == len(TASKS)  # each task's module is its own
    (tree / "envs/tasks/hammer.py").write_text("# the hammer's success rule, changed\n")
    after = versions()
    assert after["hammer"] != before["hammer"]
    assert {t: v for t, v in after.items() if t != "hammer"} == {t: v for t, v in before.items() if t != "hammer"}


def test_docs_flows_tests_and_a_new_task_module_change_nothing(tree: Path) -> None:
    before = versions()
    for rel in ("README.md", "docs/results.md", "flows/ablation.py", "envs/synthesis.py", "tests/prl/test_x.py"):
        (tree / rel).write_text("edited\n")
    (tree / "envs/tasks/hammer_mixed.py").write_text("# a new task, registered nowhere yet\n")
    (tree / "docs/new.md").write_text("new\n")
    assert versions() == before


def test_a_variant_takes_in_the_task_modules_it_imports(tree: Path) -> None:
    """A variant's version covers its base task's module and the mixin it imports (at any depth); the base task's
    version does not cover the variant."""
    (tree / "envs/tasks/mixed.py").write_text("import numpy\n")
    (tree / "envs/tasks/sweep_mixed.py").write_text(
        "from envs.tasks.mixed import MixedFamilies\nfrom envs.tasks.sweep import PRLSweepEnv\n")
    (tree / "envs/tasks/sweep.py").write_text("from envs.tasks.base import PRLTaskEnv\n")
    assert {f for f in outcome_files("sweep_mixed") if f.startswith("envs/tasks/")} == {
        "envs/tasks/__init__.py", "envs/tasks/base.py", "envs/tasks/mixed.py", "envs/tasks/sweep.py",
        "envs/tasks/sweep_mixed.py"}
    before, variant = versions(), outcome_version("sweep_mixed")
    (tree / "envs/tasks/mixed.py").write_text("import numpy  # the family draw, changed\n")
    assert outcome_version("sweep_mixed") != variant and versions() == before
    variant = outcome_version("sweep_mixed")
    (tree / "envs/tasks/sweep.py").write_text("from envs.tasks.base import PRLTaskEnv  # physics changed\n")
    assert outcome_version("sweep_mixed") != variant


@pytest.mark.parametrize("rel", ["envs/tasks/base.py", "envs/executor.py", "prl/ln.py", "assets/plb.yaml",
                                 "assets/hand/prl_hand.urdf"])
def test_shared_physics_the_ln_and_assets_change_every_task(tree: Path, rel: str) -> None:
    before = versions()
    (tree / rel).write_text("changed\n")
    after = versions()
    assert all(after[t] != before[t] for t in TASKS)


def test_a_new_asset_changes_every_task_and_an_unknown_task_is_named(tree: Path) -> None:
    before = versions()
    (tree / "assets/hand/new_part.yaml").write_text("a: 1\n")
    (tree / "assets/notes.txt").write_text("not an asset suffix\n")
    assert all(versions()[t] != before[t] for t in TASKS)
    with pytest.raises(FileNotFoundError, match="task 'hamer' has no module 'envs/tasks/hamer.py'"):
        outcome_version("hamer")
    with pytest.raises(ValueError, match="task must be a task module's name"):
        outcome_files("../README")


CATALOGUE = b"""dimensions:
  - name: kinematic_motion
tasks:
  hammer:
    prior: [0.5, 0.5]

  sweep:
    prior: [0.9, 0.1]
"""
VARIANT = b"""
  # the slanted nails' own prior
  hammer_mixed:
    prior: [0.3, 0.7]
"""


def test_a_variants_catalogue_entry_changes_its_own_version_only(tree: Path) -> None:
    """``prl.plb`` gives a variant its own entry when the catalogue has one, else its base task's: a variant's entry
    decides no other task's outcome, and a catalogue without variant entries enters every version whole."""
    (tree / "envs/tasks/hammer_mixed.py").write_text("from envs.tasks.hammer import PRLHammerEnv\n")
    (tree / "assets/plb.yaml").write_bytes(CATALOGUE)
    before = {**versions(), "hammer_mixed": outcome_version("hammer_mixed")}
    assert version.catalogue_view(CATALOGUE, "hammer") == CATALOGUE
    (tree / "assets/plb.yaml").write_bytes(CATALOGUE + VARIANT)
    assert version.catalogue_view(CATALOGUE + VARIANT, "sweep") == CATALOGUE
    assert version.catalogue_view(CATALOGUE + VARIANT, "hammer_mixed") == CATALOGUE + VARIANT
    after = {**versions(), "hammer_mixed": outcome_version("hammer_mixed")}
    assert after["hammer_mixed"] != before["hammer_mixed"]
    assert {t: v for t, v in after.items() if t != "hammer_mixed"} == {
        t: v for t, v in before.items() if t != "hammer_mixed"}
    # an entry between two others, and a base task's entry, are cut and kept by the same rule
    middle = CATALOGUE.replace(b"\n  sweep:", VARIANT + b"\n  sweep:")
    assert version.catalogue_view(middle, "unscrew_mixed") == CATALOGUE
    after_tasks = b"\nnotes:\n  hammer_mixed: a key of another section, not an entry\n"
    assert version.catalogue_view(CATALOGUE + VARIANT + after_tasks, "sweep") == CATALOGUE + after_tasks
    (tree / "assets/plb.yaml").write_bytes(CATALOGUE.replace(b"0.9, 0.1", b"0.8, 0.2") + VARIANT)
    assert all(outcome_version(t) != after[t] for t in ("hammer", "sweep", "hammer_mixed"))


def _module_file(name: str) -> str | None:
    """The repository file of a project module name, or None when it is not one."""
    parts = name.split(".")
    if parts[0] not in ("prl", "envs"):
        return None
    for rel in ("/".join(parts) + ".py", "/".join(parts) + "/__init__.py"):
        if (REPO_ROOT / rel).is_file():
            return rel
    return None


def _imports(rel: str) -> set[str]:
    """The project files ``rel`` imports anywhere (functions included), with their packages' ``__init__``."""
    found: set[str] = set()
    for node in ast.walk(ast.parse((REPO_ROOT / rel).read_text())):
        names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
        if isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        for name in names:
            parts = name.split(".")
            found.update(f for f in (_module_file(".".join(parts[:i])) for i in range(1, len(parts) + 1)) if f)
    return found


@pytest.mark.parametrize("task", known_tasks())
def test_the_list_holds_everything_its_modules_import(task: str) -> None:
    """Every project module the listed ones import, at any depth, is listed too, or left out on purpose (another
    task's module is never reached: the registry's import of the tasks is the one exception)."""
    listed = set(outcome_files(task))
    others = {f"envs/tasks/{t}.py" for t in known_tasks()} - listed
    unlisted, todo, seen = set(), [f for f in listed if f.endswith(".py")], set()
    while todo:
        rel = todo.pop()
        if rel in seen:
            continue
        seen.add(rel)
        for dep in _imports(rel):
            if dep in listed:
                todo.append(dep)
            elif dep not in LEFT_OUT and not (dep in others and rel == "envs/tasks/__init__.py"):
                unlisted.add(f"{dep} (imported by {rel})")
    assert sorted(unlisted) == []
    assert not any(f in listed for f in others)
