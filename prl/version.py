"""Code versions for cache keys, run tags and the LN's committed results (``outcome_version``)."""

from __future__ import annotations

import ast
import hashlib
import re
import subprocess
from collections.abc import Callable
from pathlib import Path

from prl.constants import REPO_ROOT
from prl.plb import DEFAULT_PLB_PATH
from prl.task_registry import base_of, declared

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
    # the simulator side every task's LN point runs, whatever its method: the package (it registers the hand agent),
    # the hand, the task base and registry, the plan executor and one plan episode's stepping (the evaluation's
    # trials import them), the LN's vector environments and the evaluation's trials
    "envs/__init__.py", "envs/agents/__init__.py", "envs/agents/prl_hand.py", "envs/hand_model.py", "envs/ik.py",
    "envs/sensors.py", "envs/tasks/__init__.py", "envs/tasks/base.py", "envs/executor.py", "envs/execution.py",
    "envs/episode.py", "envs/scene_record.py", "envs/scene_stream.py", "envs/vec_env.py", "envs/trials.py",
    "envs/reach.py",
    # the LN (A2C for every method) and what the above import from the library (the PLB, the executor's stages and
    # label maths, the demo record)
    "prl/__init__.py", "prl/ln.py", "prl/demo.py", "prl/plb.py", "prl/constants.py", "prl/geometry.py",
    "prl/labels.py", "prl/stages.py", "prl/atomic.py", "prl/shapes.py",  # the tasks build their meshes with it
    "prl/task_registry.py",
)
"""Files that decide an LN point's outcome on every task and for every method, beside the task's own module,
``assets/`` and the method's own files (``OUTCOME_METHOD_FILES``). Left out on purpose: ``prl/config.py`` (the LN's
settings enter each summary's ``settings`` as values, so editing the pipeline's profiles does not invalidate
results), ``flows/`` (orchestration and tracking; a change there to what a point computes bumps
``flows.ln_results.POINT_PROCEDURE``), other tasks' modules, the synthesis, its proposal, the export's writer and
the red team (they make the dataset, which the summaries' ``dataset_digest`` and ``dataset`` recipe cover), docs and
tests. ``tests/prl/test_version.py`` checks these lists against the modules their files import."""

OUTCOME_METHOD_FILES: dict[str, tuple[str, ...]] = {
    # plan-space methods: the plan environment and x (x_manip, text embedding, PointNet, the RN's layout of x), the
    # demonstrations' readers (the export's schema and checks: what reads an export) and their importance weights
    "plan": ("envs/plan_env.py", "prl/features.py", "prl/pointnet.py", "prl/rn.py", "prl/text_embed.py",
             "prl/export_schema.py", "prl/env_state.py", "prl/export_check.py",
             "prl/dataset_files.py", "prl/stats.py"),
    # joint-space methods: the joint-control environment and the layout of its observation
    "joint": ("envs/joint_env.py", "prl/env_state.py"),
}
"""Per method family (``method_family``), the files that decide its points' outcomes beyond ``OUTCOME_SHARED_FILES``:
editing the joint-control environment leaves every plan-space point current, and the reverse."""

OUTCOME_OWN_FILES: dict[str, tuple[str, ...]] = {
    # imitation: the LeRobot policy's training and rollout (prl.imitation), and the export's readers it trains from
    "imitation": ("prl/imitation.py", "prl/export_schema.py", "prl/export_check.py", "prl/dataset_files.py"),
    # joint_bc: the draw of the demonstrations, their replay into transitions and the cloning
    "joint_bc": ("prl/joint_bc.py", "envs/replay.py", "prl/imitation.py", "prl/export_schema.py",
                 "prl/export_check.py", "prl/dataset_files.py"),
}
"""Per method, files that decide its points' outcomes beyond its family's (``OUTCOME_METHOD_FILES``): editing the
imitation policy's training leaves every other point current."""

JOINT_METHODS: frozenset[str] = frozenset({"joint", "joint_bc", "imitation"})
"""Methods that act in joint space (``envs.joint_env``); every other method (``physics``, ``bc``, ``physics_gated``,
the reference plans) acts in the plan space."""

OUTCOME_ASSET_SUFFIXES: frozenset[str] = frozenset({".py", ".yaml", ".urdf", ".srdf"})
"""Files under ``assets/`` that enter ``outcome_version`` (the PLB catalogue, the hand model and its inputs)."""


def method_family(method: str) -> str:
    """``"joint"`` for a joint-space method (``JOINT_METHODS``), ``"plan"`` for any other LN method or reference."""
    if not isinstance(method, str) or not method:
        raise ValueError(f"method must be an LN method's name, got {method!r}")
    return "joint" if method in JOINT_METHODS else "plan"


def outcome_files(task: str, method: str = "physics") -> tuple[str, ...]:
    """The files (relative to the repository root, sorted) whose contents decide an LN point's outcome on ``task``
    with ``method``: ``envs/tasks/<task>.py`` and the task modules it imports (a variant's base task),
    ``OUTCOME_SHARED_FILES``, the method family's ``OUTCOME_METHOD_FILES``, the method's ``OUTCOME_OWN_FILES`` and
    ``assets/``
    (``OUTCOME_ASSET_SUFFIXES``). An explicit list: a module added later (another task, a variant of one) changes no
    task's files until one of these imports it. FileNotFoundError naming a task without a module."""
    own = task_module(task)
    assets = [p.relative_to(REPO_ROOT).as_posix() for p in (REPO_ROOT / "assets").rglob("*")
              if p.is_file() and p.suffix in OUTCOME_ASSET_SUFFIXES]
    family = (*OUTCOME_METHOD_FILES[method_family(method)], *OUTCOME_OWN_FILES.get(method, ()))
    return tuple(sorted({*_task_modules(own), *OUTCOME_SHARED_FILES, *family, *assets}))


def task_module(task: str) -> str:
    """The file of ``task``'s module relative to the repository root: ``envs/tasks/<task>.py`` or, for a task kept
    elsewhere in the repository, its declaration's (``prl.task_registry``). ValueError for a name that is no
    identifier or a module outside the repository; FileNotFoundError naming a task without a module."""
    if not isinstance(task, str) or not task.isidentifier():
        raise ValueError(f"task must be a task module's name, got {task!r}")
    own = f"envs/tasks/{task}.py"
    decl = declared().get(task)
    if (REPO_ROOT / own).is_file() or decl is None:
        if not (REPO_ROOT / own).is_file():
            raise FileNotFoundError(f"task {task!r} has no module {own!r} under {REPO_ROOT}")
        return own
    if not decl.module_file.is_relative_to(REPO_ROOT):
        raise ValueError(f"task {task!r}'s module {str(decl.module_file)!r} is outside the repository "
                         f"{str(REPO_ROOT)!r}: its outcome version would not be reproducible from a checkout")
    return decl.module_file.relative_to(REPO_ROOT).as_posix()


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


def outcome_file_digests(task: str, method: str = "physics",
                         read: Callable[[str], bytes | None] | None = None) -> dict[str, str]:
    """``{file: digest}`` (16 hex digits of SHA-256) of ``outcome_files(task, method)``, the PLB catalogue as
    ``task`` reads it (``catalogue_view``): what a committed LN summary records as its ``code_files``, so that a
    stale summary names the files that changed. ``read(rel)``, when given, supplies a file's bytes (None: the file
    did not exist, digest ``"-"``), e.g. from an earlier commit; by default the working tree's."""
    out = {}
    for rel in outcome_files(task, method):
        data = (REPO_ROOT / rel).read_bytes() if read is None else read(rel)
        if data is None:
            out[rel] = "-"
            continue
        if rel == PLB_CATALOGUE:
            data = catalogue_view(data, task)
        out[rel] = hashlib.sha256(data).hexdigest()[:16]
    return out


def version_of(file_digests: dict[str, str]) -> str:
    """The code version (16 hex digits) of ``{file: digest}`` (``outcome_file_digests``): one digest of the sorted
    names and digests."""
    h = hashlib.sha256()
    for rel in sorted(file_digests):
        h.update(f"{rel}\0{file_digests[rel]}\n".encode())
    return h.hexdigest()[:16]


def outcome_version(task: str, method: str = "physics") -> str:
    """The code version of what decides an LN point's outcome on ``task`` with ``method``: ``version_of`` its
    ``outcome_file_digests``, what a committed summary records as its ``code_version``. A change to the task's
    physics or success rule, the executor or the LN changes it; the joint-control environment changes the
    joint-space methods' versions only, the plan environment and the export's readers the plan-space methods'; a
    README, docs, tests, flows, another task's module or another variant's catalogue entry change none."""
    return version_of(outcome_file_digests(task, method))


def trial_version(task: str) -> str:
    """The code version of what decides a fixed plan's trial on ``task`` (``envs.trials``, the variant search):
    ``outcome_version``'s files without any method's own (``OUTCOME_METHOD_FILES``, ``OUTCOME_OWN_FILES``: the plan
    and joint environments, x, the RN, the imitation policy). A redesign of the task, an edit of the executor or of
    the task's PLB entry changes it; an edit of a learner does not."""
    learners = {f for files in (*OUTCOME_METHOD_FILES.values(), *OUTCOME_OWN_FILES.values()) for f in files}
    return version_of({f: d for f, d in outcome_file_digests(task).items() if f not in learners})


def changed_files(recorded: dict[str, str] | None, current: dict[str, str]) -> list[str] | None:
    """The files whose digest differs between a summary's ``recorded`` ``code_files`` and ``current`` ones (added,
    removed or edited), sorted; None for a summary that recorded none (the caller can say only that the version
    differs)."""
    if recorded is None:
        return None
    return sorted(f for f in {*recorded, *current} if recorded.get(f, "-") != current.get(f, "-"))


PLB_CATALOGUE = DEFAULT_PLB_PATH.relative_to(REPO_ROOT).as_posix()
"""The PLB catalogue, relative to the repository root: the one asset read per task."""

_CATALOGUE_KEY = re.compile(rb"^  ([A-Za-z0-9_]+):")
_CATALOGUE_GAP = re.compile(rb"^\s*(#.*)?$")
_CATALOGUE_SECTION = re.compile(rb"^[A-Za-z0-9_]+:")


def catalogue_view(data: bytes, task: str) -> bytes:
    """The catalogue's bytes as ``task``'s outcome reads them: everything above its ``tasks:`` section (dimensions,
    grasp patterns, motion templates) and, of that section, ``task``'s own entry or, where it has none, the entry it
    reads instead (``prl.plb``: a variant's task's, ``prl.task_registry.base_of``), each entry with the blank and
    comment lines right above its name. Another task's entry decides nothing of ``task``'s outcome, so adding a task
    to the catalogue or editing another's entry leaves ``task``'s version as it was."""
    lines = data.splitlines(keepends=True)
    start = next((i + 1 for i, line in enumerate(lines) if line.rstrip() == b"tasks:"), len(lines))
    stop = next((i for i in range(start, len(lines)) if _CATALOGUE_SECTION.match(lines[i])), len(lines))
    keys = [i for i in range(start, stop) if _CATALOGUE_KEY.match(lines[i])]
    names = [_CATALOGUE_KEY.match(lines[i]).group(1).decode() for i in keys]
    keep = task if task in names else base_of(task)
    drop: set[int] = set()
    for n, i in enumerate(keys):
        if names[n] == keep:
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
