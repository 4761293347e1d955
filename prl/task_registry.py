"""The one registry of the pipeline's tasks: each task is declared once, by its own module.

A task is a ``envs.tasks.base.PRLTaskEnv`` subclass registered with ManiSkill (``@register_env``) whose class sets
``task_name``; everything else the pipeline needs of it is a class attribute of that class (its tool and object
meshes for the point clouds, the red team's evidence fields, the unit of its measure, and, when
``assets/plb.yaml`` has no entry for it, its catalogue entry). Each such class declares itself here when it is
defined (``PRLTaskEnv.__init_subclass__`` calls ``declare``), so importing its module is enough, and the library
reads a task's declaration without importing the simulator.

Which tasks exist is known two ways that agree (a test checks it): ``known_tasks`` reads the task modules of
``envs/tasks`` as text (``repo_task_names``: the classes that set ``task_name`` to a string), so a process that never
loads the simulator (a config check, the report) knows them, and adds every task declared in this process (a task
module imported from elsewhere, e.g. a test's).

Names: a task's name is a Python identifier. A *variant* of a task (``hammer_mixed``) is a subclass of the task's
class named ``<task>_<suffix>``; a base task's name has no underscore (``DeclarationError`` says so), so that a
variant without a catalogue entry or meshes of its own reads its task's (``base_of``).
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from prl.constants import REPO_ROOT, TASKS

TASKS_DIR = REPO_ROOT / "envs" / "tasks"
"""Where the repository's task modules live (one module per task or variant)."""


class DeclarationError(ValueError):
    """A task's declaration breaks a naming rule, or two modules declare one name; the message names both."""


@dataclass(frozen=True)
class TaskDecl:
    """What the pipeline reads of one task, from its environment class's attributes."""

    name: str
    """The short name (``"hammer"``): ``PRLTaskEnv.task_name``."""
    env_id: str
    """Its registered ManiSkill environment id (``"PRL-Hammer-v1"``; empty until ``envs.tasks`` looked it up)."""
    module_file: Path
    """The file of the module that defines its class: what its outcome version covers (``prl.version``)."""
    base: str = ""
    """For a variant, its task's name (the class's nearest task ancestor); empty for a base task."""
    meshes: tuple[Callable[[Mapping[str, float]], Any], Callable[[Mapping[str, float]], Any]] | None = None
    """``(tool, object)`` mesh builders from the env's ``scene_params`` (``prl.shapes.scene_meshes``)."""
    evidence: tuple[str, ...] = ()
    """Outcome fields the red team shows with each success (``envs.red_team``)."""
    measure_unit: str = ""
    """The unit of the task's measure, its reward (``"cm"``, ``"degrees"``, ``"cubes"``): the report names it."""
    catalogue_entry: Mapping[str, Any] | None = field(default=None, compare=False)
    """``{"texts": [...], "prior": [[...], ...]}`` used when ``assets/plb.yaml`` has no entry of this name."""


_DECLARED: dict[str, TaskDecl] = {}


def check_name(name: str, base: str = "") -> None:
    """``DeclarationError`` unless ``name`` is a valid task name: an identifier; with no underscore for a base task
    (``base`` empty), ``<base>_<suffix>`` for a variant of ``base``."""
    if not isinstance(name, str) or not name.isidentifier() or name != name.lower():
        raise DeclarationError(f"task name {name!r} is not a lower-case Python identifier")
    if not base and "_" in name:
        raise DeclarationError(
            f"task name {name!r} has an underscore, which names a variant of task {name.partition('_')[0]!r}; "
            f"name a base task without one (e.g. {name.replace('_', '')!r}), or make it a subclass of that task's "
            "class")
    if base and not name.startswith(f"{base}_"):
        raise DeclarationError(f"variant {name!r} of task {base!r} must be named {base}_<suffix>")


def declare(decl: TaskDecl) -> None:
    """Record ``decl`` (a task class declares itself when defined, ``envs.tasks`` again with its environment id).
    The same module declaring the name again replaces its declaration; another module claiming a declared name is a
    ``DeclarationError`` naming both."""
    check_name(decl.name, decl.base)
    old = _DECLARED.get(decl.name)
    if old is not None and old.module_file != decl.module_file:
        raise DeclarationError(f"task {decl.name!r} is declared twice: {old.env_id} in {old.module_file} and "
                               f"{decl.env_id} in {decl.module_file}")
    _DECLARED[decl.name] = decl


def declared() -> dict[str, TaskDecl]:
    """Every task declared in this process, paper tasks first (``TASKS`` order), then by name."""
    return {n: _DECLARED[n] for n in ordered(_DECLARED)}


def declaration(task: str) -> TaskDecl:
    """The declaration of ``task``; ``KeyError`` naming the declared ones and saying how a task gets declared."""
    if task not in _DECLARED:
        raise KeyError(f"task {task!r} is not declared in this process (declared: {', '.join(ordered(_DECLARED)) or 'none'}"
                       "); its module declares it when imported: import envs.tasks, or the module of a task kept "
                       "elsewhere")
    return _DECLARED[task]


def base_of(task: str) -> str:
    """The task a variant varies (``hammer_mixed`` -> ``hammer``), or ``task`` itself for a base task: from its
    declaration when declared, else from the naming rule (``check_name``)."""
    if task in _DECLARED:
        return _DECLARED[task].base or task
    base, _, suffix = str(task).partition("_")
    return base if base and suffix else task


def ordered(names: Any) -> tuple[str, ...]:
    """``names`` de-duplicated, the paper's tasks first in ``TASKS`` order, then the others by name."""
    found = set(names)
    return tuple(t for t in TASKS if t in found) + tuple(sorted(found - set(TASKS)))


def repo_task_names(tasks_dir: Path = TASKS_DIR) -> tuple[str, ...]:
    """The tasks of the modules in ``tasks_dir``, read as text: every class that assigns ``task_name`` a string and
    does not set ``pipeline_task = False`` (a probe), in ``ordered`` order."""
    names = []
    for path in sorted(Path(tasks_dir).glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.ClassDef):
                attrs = {t.id: s.value.value for s in node.body if isinstance(s, ast.Assign)
                         and isinstance(s.value, ast.Constant) for t in s.targets if isinstance(t, ast.Name)}
                if isinstance(attrs.get("task_name"), str) and attrs["task_name"] and attrs.get("pipeline_task", True):
                    names.append(attrs["task_name"])
    return ordered(names)


def known_tasks(tasks_dir: Path = TASKS_DIR) -> tuple[str, ...]:
    """Every task a run may name: the repository's (``repo_task_names``) and any declared in this process."""
    return ordered([*repo_task_names(tasks_dir), *_DECLARED])


def units_text(decls: Mapping[str, TaskDecl]) -> str:
    """The base tasks of ``decls`` grouped by the unit of their measure, units in order of first use:
    ``"hammer and tweeze cm, sweep cubes, unscrew degrees"`` (what the report says of its rewards)."""
    by_unit: dict[str, list[str]] = {}
    for name in ordered(decls):
        if not decls[name].base and decls[name].measure_unit:
            by_unit.setdefault(decls[name].measure_unit, []).append(name)
    return ", ".join(f"{' and '.join(names)} {unit}" for unit, names in by_unit.items())
