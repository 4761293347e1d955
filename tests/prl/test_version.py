"""``prl.version.outcome_version``: the code version of what decides an LN point's outcome on one task, on a copy
of the file layout in a temporary tree and against the imports of the listed modules."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from prl import version
from prl.constants import REPO_ROOT, TASKS
from prl.task_registry import known_tasks
from prl.version import (
    OUTCOME_METHOD_FILES,
    OUTCOME_OWN_FILES,
    OUTCOME_SHARED_FILES,
    changed_files,
    method_family,
    outcome_file_digests,
    outcome_files,
    outcome_version,
    version_of,
)

LEFT_OUT = {"prl/config.py", "envs/tasks/grasp_probe.py"}
"""Modules the listed files import that do not decide an outcome (see ``OUTCOME_SHARED_FILES``' docstring)."""
LEFT_OUT_JOINT = {"prl/features.py"}
"""Left out of the joint-space methods' files: ``prl/ln.py`` imports it in its plan-space helpers alone (the x of
the demonstrations and of a scene), which a joint-space point never calls."""


@pytest.fixture()
def tree(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A checkout's layout with placeholder contents, which ``prl.version`` takes for the repository."""
    for rel in [*OUTCOME_SHARED_FILES, *(f for files in OUTCOME_METHOD_FILES.values() for f in files),
                *(f for files in OUTCOME_OWN_FILES.values() for f in files),
                *(f"envs/tasks/{t}.py" for t in TASKS), "assets/plb.yaml",
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


def test_a_trials_version_leaves_out_the_learners(tree: Path) -> None:
    """``trial_version`` (a variant search's record): the task's module and the executor change it, a learner's files
    (the plan environment, the RN, the imitation policy) change an LN point's version but not a trial's."""
    before, points = {t: version.trial_version(t) for t in TASKS}, versions()
    assert len(set(before.values())) == len(TASKS) and before["hammer"] != points["hammer"]
    for rel in ("envs/plan_env.py", "prl/rn.py", "prl/imitation.py", "envs/joint_env.py"):
        (tree / rel).write_text("# a learner, changed\n")
    assert {t: version.trial_version(t) for t in TASKS} == before
    assert all(v != points[t] for t, v in versions().items())  # the LN points' versions did change
    (tree / "envs/executor.py").write_text("# the executor, changed\n")
    after = {t: version.trial_version(t) for t in TASKS}
    assert all(after[t] != before[t] for t in TASKS)
    (tree / "envs/tasks/hammer.py").write_text("# the hammer, redesigned\n")
    assert [t for t in TASKS if version.trial_version(t) != after[t]] == ["hammer"]


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


def test_each_methods_own_files_change_its_versions_only(tree: Path) -> None:
    """The joint-control environment decides the joint-space methods' outcomes alone, the plan environment the
    plan-space methods' alone, the export's readers theirs and the joint-space methods that learn from an export
    (imitation, joint_bc), the imitation policy's training and the demonstrations' draw those two, the cloning
    joint_bc's alone; the shared executor every one."""
    def all_versions() -> dict[tuple[str, str], str]:
        return {(t, m): outcome_version(t, m) for t in TASKS for m in ("physics", "bc", "reference", "joint",
                                                                        "joint_bc", "imitation")}

    before = all_versions()
    (tree / "envs/joint_env.py").write_text("# the joint limits looked up by name\n")
    after = all_versions()
    assert {k for k in before if before[k] != after[k]} == {(t, m) for t in TASKS
                                                            for m in ("joint", "joint_bc", "imitation")}
    for rel in ("envs/plan_env.py", "prl/export_schema.py"):
        before = all_versions()
        (tree / rel).write_text(f"# {rel}, edited\n")
        after = all_versions()
        readers = ("imitation", "joint_bc") if "export" in rel else ()
        assert {k for k in before if before[k] != after[k]} == {
            (t, m) for t in TASKS for m in ("physics", "bc", "reference", *readers)}
    before = all_versions()
    (tree / "prl/imitation.py").write_text("# the policy's training and the draw of the demonstrations, edited\n")
    assert {k for k, v in all_versions().items() if v != before[k]} == {(t, m) for t in TASKS
                                                                        for m in ("imitation", "joint_bc")}
    before = all_versions()
    (tree / "prl/joint_bc.py").write_text("# the cloning, edited\n")
    assert {k for k, v in all_versions().items() if v != before[k]} == {(t, "joint_bc") for t in TASKS}
    before = all_versions()
    (tree / "envs/executor.py").write_text("# shared\n")
    assert all(v != before[k] for k, v in all_versions().items())
    assert method_family("physics_gated") == "plan" and method_family("imitation") == "joint"
    with pytest.raises(ValueError, match="method must be an LN method's name"):
        outcome_files("hammer", "")


def test_file_digests_name_what_changed(tree: Path) -> None:
    """A summary's ``code_files`` make its ``code_version``, and name the files edited, added or removed since."""
    files = outcome_file_digests("sweep", "joint")
    assert version_of(files) == outcome_version("sweep", "joint")
    assert set(files) == set(outcome_files("sweep", "joint")) and "envs/plan_env.py" not in files
    (tree / "envs/joint_env.py").write_text("# edited\n")
    (tree / "assets/hand/new_part.yaml").write_text("a: 1\n")
    now = outcome_file_digests("sweep", "joint")
    assert changed_files(files, now) == ["assets/hand/new_part.yaml", "envs/joint_env.py"]
    assert changed_files(files, files) == [] and changed_files(None, now) is None
    gone = outcome_file_digests("sweep", "joint", read=lambda rel: None if rel == "envs/joint_env.py" else b"x")
    assert gone["envs/joint_env.py"] == "-" and version_of(gone) != version_of(now)


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


def test_a_catalogue_entry_changes_its_own_tasks_version_only(tree: Path) -> None:
    """``prl.plb`` gives a task its own entry, a variant without one its base task's: a task's version covers the
    catalogue above ``tasks:`` and the one entry it reads, so adding a task's entry or editing another's changes no
    other task's version."""
    (tree / "envs/tasks/hammer_mixed.py").write_text("from envs.tasks.hammer import PRLHammerEnv\n")
    (tree / "assets/plb.yaml").write_bytes(CATALOGUE)
    head, hammer, sweep = CATALOGUE[:CATALOGUE.index(b"  hammer:")], b"  hammer:\n    prior: [0.5, 0.5]\n", (
        b"\n  sweep:\n    prior: [0.9, 0.1]\n")
    assert version.catalogue_view(CATALOGUE, "hammer") == head + hammer
    assert version.catalogue_view(CATALOGUE, "sweep") == head + sweep  # its blank line above is its own
    assert version.catalogue_view(CATALOGUE, "hammer_mixed") == head + hammer  # a variant without an entry
    before = {**versions(), "hammer_mixed": outcome_version("hammer_mixed")}
    (tree / "assets/plb.yaml").write_bytes(CATALOGUE + VARIANT)
    assert version.catalogue_view(CATALOGUE + VARIANT, "sweep") == head + sweep
    assert version.catalogue_view(CATALOGUE + VARIANT, "hammer_mixed") == head + VARIANT
    after = {**versions(), "hammer_mixed": outcome_version("hammer_mixed")}
    assert after["hammer_mixed"] != before["hammer_mixed"]
    assert {t: v for t, v in after.items() if t != "hammer_mixed"} == {
        t: v for t, v in before.items() if t != "hammer_mixed"}
    # an entry between two others is cut by the same rule; another section after tasks: stays in every view
    middle = CATALOGUE.replace(b"\n  sweep:", VARIANT + b"\n  sweep:")
    assert version.catalogue_view(middle, "sweep") == head + sweep
    after_tasks = b"\nnotes:\n  hammer_mixed: a key of another section, not an entry\n"
    assert version.catalogue_view(CATALOGUE + VARIANT + after_tasks, "sweep") == head + sweep + after_tasks
    # editing the sweep's entry changes the sweep's version alone; editing above tasks: changes every one
    (tree / "assets/plb.yaml").write_bytes(CATALOGUE.replace(b"0.9, 0.1", b"0.8, 0.2") + VARIANT)
    edited = {**versions(), "hammer_mixed": outcome_version("hammer_mixed")}
    assert [t for t in edited if edited[t] != after[t]] == ["sweep"]
    (tree / "assets/plb.yaml").write_bytes(CATALOGUE.replace(b"kinematic_motion", b"motion") + VARIANT)
    assert all(outcome_version(t) != edited[t] for t in ("hammer", "sweep", "hammer_mixed"))


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


@pytest.mark.parametrize("method", ["physics", "joint", "imitation", "joint_bc"])
@pytest.mark.parametrize("task", known_tasks())
def test_the_list_holds_everything_its_modules_import(task: str, method: str) -> None:
    """Every project module the listed ones import, at any depth, is listed too, or left out on purpose (another
    task's module is never reached: the registry's import of the tasks is the one exception); for each method
    family apart, so that the joint-control environment is not reached from the plan space's files."""
    listed = set(outcome_files(task, method))
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
            elif dep not in LEFT_OUT and not (method != "physics" and dep in LEFT_OUT_JOINT) and not (dep in others and rel == "envs/tasks/__init__.py"):
                unlisted.add(f"{dep} (imported by {rel})")
    assert sorted(unlisted) == []
    assert not any(f in listed for f in others)


def test_no_committed_plan_space_summary_is_stale() -> None:
    """The committed LN results: every plan-space point and reference row ran on today's code of its task and method
    (an edit of the joint-control environment or of the export's writer must leave them current). The one way such a
    point may go stale is a redesign of its own task (a mixed variant whose families changed): then its task's own
    module and its own catalogue entry (``assets/plb.yaml`` as the task reads it: an edit above ``tasks:`` would
    stale every task) are the only files that changed, and the report lists the point apart until it is run
    again."""
    from prl.ln_reference import read_references, reference_file_name
    from prl.ln_summary import read_summaries, stale_points
    from prl.version import method_family

    results = REPO_ROOT / "docs" / "results" / "ln"
    summaries = read_summaries(results)
    references = {reference_file_name(t).removesuffix(".json"): r for t, r in read_references(results).items()}
    stale = stale_points({**summaries, **references})
    plan_stale = {n: why for n, why in stale.items()
                  if n in references or method_family(summaries[n]["point"]["method"]) == "plan"}
    task_of = {n: (references[n]["task"] if n in references else summaries[n]["point"]["task"]) for n in plan_stale}
    own = {n: {f"changed: `envs/tasks/{task_of[n]}.py`", f"changed: `assets/plb.yaml`, `envs/tasks/{task_of[n]}.py`"}
           for n in plan_stale}
    redesigned = {n: why for n, why in plan_stale.items() if why in own[n]}
    assert {n: why for n, why in plan_stale.items() if n not in redesigned} == {}
