"""Code versions for cache keys, run tags and the LN's committed results (``outcome_version``)."""

from __future__ import annotations

import ast
import hashlib
import re
import subprocess
from collections.abc import Callable
from pathlib import Path

from prl.constants import REPO_ROOT, TASKS
from prl.plb import DEFAULT_PLB_PATH

_SOURCE_DIRS = ("prl", "envs", "assets")


def code_version() -> str:
    """A digest of the library sources and assets (tracked or not), stable across checkouts."""
    h = hashlib.sha256()
    for d in _SOURCE_DIRS:
        for path in sorted((REPO_ROOT / d).rglob("*")):
            if path.is_file() and path.suffix in {".py", ".yaml", ".urdf", ".srdf"}:
                h.update(str(path.relative_to(REPO_ROOT)).encode())
                h.update(path.read_bytes())
    return h.hexdigest()[:16]


OUTCOME_SHARED_FILES: tuple[str, ...] = (
    # the simulator side every task's LN point runs: the package (it registers the hand agent), the hand, the
    # task base and registry, the plan executor and one plan episode's stepping, the LN's environments and the
    # evaluation's trials (``run_policy``, ``run_joint_policy``)
    "envs/__init__.py", "envs/agents/__init__.py", "envs/agents/prl_hand.py", "envs/hand_model.py", "envs/ik.py",
    "envs/sensors.py", "envs/tasks/__init__.py", "envs/tasks/base.py", "envs/executor.py", "envs/execution.py",
    "envs/episode.py", "envs/scene_record.py", "envs/scene_stream.py", "envs/plan_env.py", "envs/joint_env.py",
    "envs/vec_env.py", "envs/trials.py", "envs/reach.py",
    # the LN and what it imports from the library (x: x_manip, text embedding, PointNet, its layout; the PLB;
    # the executor's stages and label maths; the dataset readers of the demonstrations' x)
    "prl/__init__.py", "prl/ln.py", "prl/features.py", "prl/demo.py", "prl/pointnet.py", "prl/rn.py",
    "prl/text_embed.py", "prl/shapes.py", "prl/plb.py", "prl/constants.py", "prl/geometry.py", "prl/labels.py",
    "prl/stages.py", "prl/atomic.py", "prl/export_schema.py", "prl/export_check.py", "prl/dataset_files.py",
    "prl/stats.py",  # the demonstrations' importance weights
)
"""Files that decide an LN point's outcome on every task, beside the task's own module and ``assets/``. Left out
on purpose: ``prl/config.py`` (the LN's settings enter each summary's ``settings`` as values, so editing the
pipeline's profiles does not invalidate results), ``flows/`` (orchestration and tracking; a change there to what
a point computes bumps ``flows.ln_results.POINT_PROCEDURE``), other tasks' modules, the synthesis, its proposal and the red team
(they make the dataset, which the summaries' ``dataset_digest`` and ``dataset`` recipe cover), docs and tests.
``tests/prl/test_version.py`` checks this list against the modules these files import."""

OUTCOME_ASSET_SUFFIXES: frozenset[str] = frozenset({".py", ".yaml", ".urdf", ".srdf"})
"""Files under ``assets/`` that enter ``outcome_version`` (the PLB catalogue, the hand model and its inputs)."""


def outcome_files(task: str) -> tuple[str, ...]:
    """The files (relative to the repository root, sorted) whose contents decide an LN point's outcome on
    ``task``: ``envs/tasks/<task>.py`` and the task modules it imports (a variant's base task), ``OUTCOME_SHARED_FILES`` and ``assets/`` (``OUTCOME_ASSET_SUFFIXES``).
    An explicit list: a module added later (another task, a variant of one) changes no task's files until one of
    these imports it. FileNotFoundError naming a task without a module, or a listed file that is missing."""
    if not isinstance(task, str) or not task.isidentifier():
        raise ValueError(f"task must be a task module's name, got {task!r}")
    own = f"envs/tasks/{task}.py"
    if not (REPO_ROOT / own).is_file():
        raise FileNotFoundError(f"task {task!r} has no module {own!r} under {REPO_ROOT}")
    assets = [p.relative_to(REPO_ROOT).as_posix() for p in (REPO_ROOT / "assets").rglob("*")
              if p.is_file() and p.suffix in OUTCOME_ASSET_SUFFIXES]
    return tuple(sorted({*_task_modules(own), *OUTCOME_SHARED_FILES, *assets}))


def _task_modules(own: str) -> set[str]:
    """``own`` (a task's module) and the task modules it imports, at any depth: a variant
    (``envs/tasks/unscrew_mixed.py``) decides its outcomes with its base task's module and the mixin it imports."""
    found, todo = set(), [own]
    while todo:
        rel = todo.pop()
        if rel in found:
            continue
        found.add(rel)
        for node in ast.walk(ast.parse((REPO_ROOT / rel).read_text(), filename=rel)):
            if isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").startswith("envs.tasks."):
                dep = node.module.replace(".", "/") + ".py"
                if (REPO_ROOT / dep).is_file():
                    todo.append(dep)
    return found


def outcome_version(task: str) -> str:
    """A digest (16 hex digits) of the names and bytes of ``outcome_files(task)``: what a committed LN summary of
    ``task`` records as its ``code_version``. A change to the task's physics or success rule, the executor or the
    LN changes it; a README, docs, tests, flows, another task's module or another variant's catalogue entry do
    not (``catalogue_view``)."""
    return source_version(*outcome_files(task), view=lambda rel, data: catalogue_view(data, task)
                          if rel == PLB_CATALOGUE else data)


PLB_CATALOGUE = DEFAULT_PLB_PATH.relative_to(REPO_ROOT).as_posix()
"""The PLB catalogue, relative to the repository root: the one asset read per task."""

_CATALOGUE_KEY = re.compile(rb"^  ([A-Za-z0-9_]+):")
_CATALOGUE_GAP = re.compile(rb"^\s*(#.*)?$")
_CATALOGUE_SECTION = re.compile(rb"^[A-Za-z0-9_]+:")


def catalogue_view(data: bytes, task: str) -> bytes:
    """The catalogue's bytes as ``task``'s outcome reads them: the whole file less the entries of *variants* other
    than ``task`` (entries of the ``tasks:`` section whose name is not one of ``prl.constants.TASKS``), each with the
    blank and comment lines right above its name. ``prl.plb`` gives a task its own entry or, for a variant without
    one, its base task's, so a variant's entry decides no other task's outcome; the base tasks' entries and
    everything above ``tasks:`` stay in every view. A file with no variant entry is its own view, byte for byte."""
    lines = data.splitlines(keepends=True)
    start = next((i + 1 for i, line in enumerate(lines) if line.rstrip() == b"tasks:"), len(lines))
    stop = next((i for i in range(start, len(lines)) if _CATALOGUE_SECTION.match(lines[i])), len(lines))
    keys = [i for i in range(start, stop) if _CATALOGUE_KEY.match(lines[i])]
    drop: set[int] = set()
    for n, i in enumerate(keys):
        name = _CATALOGUE_KEY.match(lines[i]).group(1).decode()
        if name in TASKS or name == task:
            continue
        first = i
        while first > start and _CATALOGUE_GAP.match(lines[first - 1]) and first - 1 not in drop:
            first -= 1
        end = keys[n + 1] if n + 1 < len(keys) else stop
        while end > i + 1 and _CATALOGUE_GAP.match(lines[end - 1]) and end < len(lines):
            end -= 1  # the blank and comment lines above the next entry (or section) are its own
        drop.update(range(first, end))
    return b"".join(line for j, line in enumerate(lines) if j not in drop)


def source_version(*relative_paths: str, view: Callable[[str, bytes], bytes] | None = None) -> str:
    """A digest of the named source files (paths relative to the repository root), for caches that depend
    on those files alone; ``view(path, bytes)``, when given, is what enters the digest of each file. A missing file
    raises FileNotFoundError naming it."""
    h = hashlib.sha256()
    for rel in relative_paths:
        path = REPO_ROOT / rel
        if not path.is_file():
            raise FileNotFoundError(f"source file {rel!r} not found under {REPO_ROOT}")
        h.update(rel.encode())
        data = path.read_bytes()
        h.update(view(rel, data) if view else data)
    return h.hexdigest()[:16]


def file_digest(path: str | Path) -> str:
    """SHA-256 (hex) of one file's bytes; FileNotFoundError names a missing file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"file not found: {path}")
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def git_commit() -> str:
    """The checked-out git commit, or 'unknown'."""
    try:
        res = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO_ROOT, capture_output=True, text=True,
                             timeout=10, check=False)
        return res.stdout.strip() or "unknown"
    except OSError:
        return "unknown"
