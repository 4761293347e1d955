"""LeRobot dataset export (format v3.0) of saved demonstrations (DESIGN.md sec. 3 step 4).

One episode per demonstration (``prl.demo.Demo``), one frame per recorded step, the episode's
task being the demo's task sentence. The dataset is written with the ``lerobot`` package
(``LeRobotDataset.create`` -> ``add_frame`` -> ``save_episode`` -> ``finalize``) into a staging
directory next to the destination, reloaded with ``LeRobotDataset(repo_id, root=staging)`` and
validated against the demos, and only then moved into place: a failed or killed export never
leaves a broken dataset where a good one was.

Frame layout (``FEATURES``, the one place where names, shapes and dtypes are declared):

==============================  ===========  =====  ==============================================
feature                         shape        dtype  content
==============================  ===========  =====  ==============================================
observation.state               (60,)        f32    qpos (30) | qvel (30)
action                          (30,)        f32    joint drive targets
observation.contact_force       (17,)        f32    sensor force per patch
observation.contact_position    (51,)        f32    (17, 3) contact points, row-major
observation.contact_normal      (51,)        f32    (17, 3) contact normals, row-major
observation.palm_pose           (7,)         f32    position xyz | quaternion wxyz (SAPIEN order)
observation.tool_pose           (7,)         f32    idem
observation.object_pose         (7,)         f32    idem
stage                           (1,)         i64    executor stage index (``envs.executor.STAGES``)
plan                            (6,)         i64    commanded plan, constant over the episode
label                           (6,)         i64    recovered physical-law label, or -1s
x_manip                         (784,)       f32    observation-phase features (before the plan acts), constant
==============================  ===========  =====  ==============================================

lerobot adds ``timestamp``, ``frame_index``, ``episode_index``, ``index`` and ``task_index``.

Reloading is offline: ``LeRobotDataset(repo_id, root=...)`` reads a complete local root without
touching the Hub, but falls back to a Hub download when local files are missing (and creates
``root`` if it does not exist). :func:`validate_lerobot` therefore checks the files on disk with
pyarrow first and only then hands the root to lerobot.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import json
import os
import shutil
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from prl.constants import JOINT_NAMES, N_JOINTS, N_SENSORS, RECORD_HZ, RS_DIMS, SENSOR_NAMES

CODEBASE_VERSION = "v3.0"
"""LeRobot dataset format written and accepted."""
DEFAULT_REPO_ID = "prl/hammer"
"""Default dataset identifier (only a name: nothing is pushed to the Hub)."""
SCENES_FILE = "meta/prl_scenes.jsonl"
"""Sidecar written next to lerobot's metadata: one JSON line per episode with its scene (see
:func:`read_scenes`); lerobot itself ignores it."""
EXPORT_KEY_FILE = "meta/prl_export_key.txt"
"""The key of the inputs an export was written from (:func:`export_key`), for :func:`reusable_export`."""
DEFAULT_FPS = RECORD_HZ
"""Recording rate of the demos (``prl.constants.RECORD_HZ``, the executor's record interval)."""
ROBOT_TYPE = "prl_hand"
"""``robot_type`` written to ``meta/info.json`` (the agent's uid)."""
NO_LABEL = -1
"""Label value of an episode without a recovered physical-law label."""
PLAN_DIM = len(RS_DIMS)
"""Length of plan and label vectors (6)."""

_POSE_NAMES = ["x", "y", "z", "qw", "qx", "qy", "qz"]
_XYZ = ("x", "y", "z")

FEATURES: dict[str, dict[str, Any]] = {
    "observation.state": {
        "dtype": "float32", "shape": (2 * N_JOINTS,),
        "names": [f"{j}.pos" for j in JOINT_NAMES] + [f"{j}.vel" for j in JOINT_NAMES],
    },
    "action": {"dtype": "float32", "shape": (N_JOINTS,), "names": [f"{j}.target" for j in JOINT_NAMES]},
    "observation.contact_force": {"dtype": "float32", "shape": (N_SENSORS,), "names": list(SENSOR_NAMES)},
    "observation.contact_position": {
        "dtype": "float32", "shape": (3 * N_SENSORS,), "names": [f"{s}.{a}" for s in SENSOR_NAMES for a in _XYZ],
    },
    "observation.contact_normal": {
        "dtype": "float32", "shape": (3 * N_SENSORS,), "names": [f"{s}.n{a}" for s in SENSOR_NAMES for a in _XYZ],
    },
    "observation.palm_pose": {"dtype": "float32", "shape": (7,), "names": list(_POSE_NAMES)},
    "observation.tool_pose": {"dtype": "float32", "shape": (7,), "names": list(_POSE_NAMES)},
    "observation.object_pose": {"dtype": "float32", "shape": (7,), "names": list(_POSE_NAMES)},
    "stage": {"dtype": "int64", "shape": (1,), "names": None},
    "plan": {"dtype": "int64", "shape": (PLAN_DIM,), "names": None},
    "label": {"dtype": "int64", "shape": (PLAN_DIM,), "names": None},
    "x_manip": {"dtype": "float32", "shape": (784,), "names": None},
}
"""Every exported feature: lerobot feature spec (dtype, shape, names). The single declaration."""

_PER_EPISODE = ("plan", "label", "x_manip")
"""Features constant over an episode."""


class ExportError(RuntimeError):
    """An export or a validation failed; the message says what and where."""


@dataclass(frozen=True)
class EpisodeCheck:
    """What one exported episode must hold, taken from its demo (for :func:`validate_lerobot`)."""

    length: int
    """Frames (the demo's record count)."""
    task: str
    """Task sentence."""
    plan: tuple[int, ...]
    """Commanded plan."""
    label: tuple[int, ...]
    """Label vector written (``NO_LABEL`` s when none)."""
    sample_index: int
    """Frame index (within the episode) whose state is compared."""
    sample_state: np.ndarray = field(repr=False)
    """Expected ``observation.state`` at ``sample_index`` (float32)."""
    source: str = ""
    """Demo file, for error messages."""


@dataclass(frozen=True)
class ExportReport:
    """Outcome of an export or of a validation of a dataset on disk."""

    root: Path
    """Dataset root (after an export: the destination)."""
    repo_id: str
    """Dataset identifier."""
    fps: int
    """Frames per second in ``meta/info.json``."""
    n_episodes: int
    """Episodes."""
    n_frames: int
    """Frames over all episodes."""
    episode_lengths: tuple[int, ...]
    """Frames per episode, by episode index."""
    tasks: tuple[str, ...]
    """Task sentence per episode, by episode index."""
    n_labelled: int
    """Episodes whose label is not all ``NO_LABEL``."""
    size_bytes: int
    """Bytes of all files under ``root``."""
    seconds: float
    """Wall time of the export (write + validate + move) or of the validation alone."""
    checked_against_demos: bool = False
    """True when episodes were compared with their demos (lengths, tasks, plan, label, a state)."""
    reused: bool = False
    """True when an identical earlier export was found, reloaded and validated instead of rewritten."""


# ----------------------------------------------------------------------------- export


def export_lerobot(
    demo_paths: Sequence[Path | str],
    root: Path | str,
    repo_id: str = DEFAULT_REPO_ID,
    fps: int = DEFAULT_FPS,
    per_episode_label: Mapping[Any, Sequence[int] | np.ndarray] | None = None,
    *,
    render_video: bool = False,
    fast_writes: bool = True,
    key: str | None = None,
) -> ExportReport:
    """Export demos (``prl.demo`` ``.npz`` files) as a LeRobot v3.0 dataset at ``root``.

    Episode ``i`` is ``demo_paths[i]``. ``per_episode_label`` maps a demo's path (as given, as
    string or resolved) or its scene seed to its (6,) recovered physical-law label; episodes
    without one get ``NO_LABEL`` s. ``render_video`` is reserved: rendering is not implemented,
    the dataset is written with ``use_videos=False`` and passing True raises NotImplementedError.
    ``fast_writes`` skips lerobot's per-frame image-embedding pass, a no-op without image
    features that costs ~6 ms a frame (see :func:`_quiet_fast_writes`); the files are the same.
    ``key`` (from :func:`export_key`) is written to ``EXPORT_KEY_FILE`` so that a later identical
    export can be skipped with :func:`reusable_export`.

    The dataset is written into ``root.parent / f".{root.name}.staging-<pid>"``, finalized,
    reloaded with ``LeRobotDataset`` and validated against the demos (:func:`validate_lerobot`);
    then it replaces ``root`` atomically (``renameat2(RENAME_EXCHANGE)`` where supported, else
    old-aside / new-in / old-removed). On any failure the staging directory is removed and an
    existing dataset at ``root`` is left untouched. Leftovers of a killed export (a staging or
    set-aside directory whose process is gone) are cleaned up or restored on the next export.

    Raises TypeError (a single path instead of a sequence), ValueError (no demo paths, bad
    argument, unreadable or inconsistent demo: the message names the file), FileNotFoundError (a
    missing demo: named), NotADirectoryError / PermissionError (destination not usable),
    ExportError (the written dataset failed validation).
    """
    t0 = time.perf_counter()
    if isinstance(demo_paths, (str, Path)):
        raise TypeError(f"demo_paths must be a sequence of paths, got the single path {str(demo_paths)!r}")
    paths = [Path(p) for p in demo_paths]
    if not paths:
        raise ValueError("no demo paths given: a LeRobot export needs at least one demonstration")
    if render_video:
        raise NotImplementedError("render_video=True: video rendering is not implemented yet (use_videos=False)")
    if isinstance(fps, bool) or not isinstance(fps, int) or fps <= 0:
        raise ValueError(f"fps must be a positive integer, got {fps!r}")
    if not isinstance(repo_id, str) or not repo_id.strip():
        raise ValueError(f"repo_id must be a non-empty string, got {repo_id!r}")
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise FileNotFoundError(f"demo file {missing[0]!r} does not exist{more}")

    root = Path(os.path.abspath(root))
    _check_destination(root)
    _recover_stale(root)
    staging = root.parent / f".{root.name}.staging-{os.getpid()}"
    if staging.exists():
        shutil.rmtree(staging)
    try:
        with _quiet_fast_writes(fast=fast_writes):
            checks = _write(paths, staging, repo_id, fps, per_episode_label)
            if key is not None:
                (staging / EXPORT_KEY_FILE).write_text(key + "\n")
            report = validate_lerobot(staging, repo_id, expected=checks, drop_cache=True)
        _move_into_place(staging, root)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return ExportReport(
        root=root, repo_id=repo_id, fps=report.fps, n_episodes=report.n_episodes, n_frames=report.n_frames,
        episode_lengths=report.episode_lengths, tasks=report.tasks, n_labelled=report.n_labelled,
        size_bytes=_tree_size(root), seconds=time.perf_counter() - t0, checked_against_demos=True,
    )


def export_key(demo_paths: Sequence[Path | str], labels: Mapping[str, Sequence[int]] | None, repo_id: str,
               fps: int, code_version: str) -> str:
    """A digest of everything an export is made from: each demo file's name and bytes, in order, its
    label (looked up by the path as given), ``repo_id``, ``fps`` and ``code_version``. Demo files are
    written once and never change, so an equal key means an equal dataset."""
    import hashlib

    h = hashlib.sha256(json.dumps([repo_id, fps, code_version]).encode())
    for p in demo_paths:
        path = Path(p)
        label = None if labels is None else labels.get(str(p))
        h.update(json.dumps([path.name, None if label is None else [int(v) for v in label]]).encode())
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()[:20]


def reusable_export(root: Path | str, repo_id: str, key: str) -> ExportReport | None:
    """The validated report of the dataset at ``root`` if it was exported with ``key``; else None.

    The dataset is still reloaded with ``LeRobotDataset`` and checked (:func:`validate_lerobot`), so a
    damaged one raises ExportError instead of being reused."""
    t0 = time.perf_counter()
    root = Path(os.path.abspath(root))
    stored = root / EXPORT_KEY_FILE
    if not stored.is_file() or stored.read_text().strip() != key:
        return None
    report = validate_lerobot(root, repo_id, drop_cache=True)
    return replace(report, size_bytes=_tree_size(root), seconds=time.perf_counter() - t0, reused=True)


def lerobot_features() -> dict[str, dict[str, Any]]:
    """A fresh copy of ``FEATURES`` for ``LeRobotDataset.create`` (which must not alias ours)."""
    return {name: {**spec, "shape": tuple(spec["shape"]),
                   "names": list(spec["names"]) if spec["names"] is not None else None}
            for name, spec in FEATURES.items()}


def episode_frames(demo: Any, label: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """``{feature: (T, *shape) array}`` of one demo, dtypes as in ``FEATURES`` (raises ValueError)."""
    t = int(np.asarray(demo.stage).shape[0])
    if t == 0:
        raise ValueError("the demo has no recorded frame")

    def arr(name: str, shape: tuple[int, ...]) -> np.ndarray:
        a = np.asarray(getattr(demo, name))
        if a.shape != (t, *shape):
            raise ValueError(f"array {name!r} has shape {a.shape}, expected {(t, *shape)}")
        return a

    plan = np.asarray(demo.plan)
    if plan.shape != (PLAN_DIM,):
        raise ValueError(f"plan has shape {plan.shape}, expected ({PLAN_DIM},)")
    lab = np.full(PLAN_DIM, NO_LABEL, np.int64) if label is None else _as_label(label)
    xm = np.asarray(demo.x_manip)
    if xm.shape != FEATURES["x_manip"]["shape"]:
        raise ValueError(f"x_manip has shape {xm.shape}, expected {FEATURES['x_manip']['shape']}")
    out = {
        "observation.state": np.concatenate([arr("qpos", (N_JOINTS,)), arr("qvel", (N_JOINTS,))], axis=1),
        "action": arr("target", (N_JOINTS,)),
        "observation.contact_force": arr("force", (N_SENSORS,)),
        "observation.contact_position": arr("contact_pos", (N_SENSORS, 3)).reshape(t, -1),
        "observation.contact_normal": arr("contact_normal", (N_SENSORS, 3)).reshape(t, -1),
        "observation.palm_pose": arr("palm_pose", (7,)),
        "observation.tool_pose": arr("tool_pose", (7,)),
        "observation.object_pose": arr("object_pose", (7,)),
        "stage": arr("stage", ()).reshape(t, 1),
        "plan": np.broadcast_to(plan, (t, PLAN_DIM)),
        "label": np.broadcast_to(lab, (t, PLAN_DIM)),
        "x_manip": np.broadcast_to(xm, (t, xm.size)),
    }
    assert out.keys() == FEATURES.keys()
    frames = {}
    for name, a in out.items():
        spec = FEATURES[name]
        if spec["dtype"] == "int64" and not np.issubdtype(a.dtype, np.integer):
            raise ValueError(f"feature {name!r} must be integer, got dtype {a.dtype}")
        frames[name] = np.ascontiguousarray(a, dtype=spec["dtype"])
        if not np.all(np.isfinite(frames[name])):
            raise ValueError(f"feature {name!r} holds non-finite values")
    return frames


def _as_label(label: Sequence[int] | np.ndarray) -> np.ndarray:
    a = np.asarray(label)
    if a.shape != (PLAN_DIM,):
        raise ValueError(f"label must have shape ({PLAN_DIM},), got {a.shape} ({label!r})")
    if not (np.issubdtype(a.dtype, np.integer) or (np.issubdtype(a.dtype, np.floating) and np.all(a == np.round(a)))):
        raise ValueError(f"label must hold integers, got {label!r}")
    return a.astype(np.int64)


def _label_for(path: Path, seed: int, labels: Mapping[Any, Any] | None) -> np.ndarray | None:
    if not labels:
        return None
    for key in (path, str(path), path.resolve(), str(path.resolve()), seed):
        if key in labels:
            return _as_label(labels[key])
    return None


def _load(path: Path) -> Any:
    from prl.demo import load_demo

    try:
        return load_demo(path)
    except FileNotFoundError:
        raise
    except ValueError:  # load_demo's message already names the file
        raise
    except Exception as exc:  # e.g. zipfile.BadZipFile from a truncated archive
        raise ValueError(f"demo file {str(path)!r} is unreadable: {type(exc).__name__}: {exc}") from exc


def _write(paths: list[Path], staging: Path, repo_id: str, fps: int,
           labels: Mapping[Any, Any] | None) -> list[EpisodeCheck]:
    """Write every demo as an episode into ``staging`` (create -> add_frame -> save_episode -> finalize)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset.create(repo_id, fps=fps, features=lerobot_features(), root=staging,
                               robot_type=ROBOT_TYPE, use_videos=False)
    checks: list[EpisodeCheck] = []
    scenes: list[dict[str, Any]] = []
    try:
        for path in paths:
            demo = _load(path)
            text = demo.text
            if not isinstance(text, str) or not text.strip():
                raise ValueError(f"demo file {str(path)!r} has no task sentence (text={text!r})")
            try:
                frames = episode_frames(demo, _label_for(path, demo.seed, labels))
            except ValueError as exc:
                raise ValueError(f"demo file {str(path)!r} is inconsistent: {exc}") from exc
            t = frames["stage"].shape[0]
            for i in range(t):
                ds.add_frame({**{name: a[i] for name, a in frames.items()}, "task": text})
            ds.save_episode()
            scenes.append({"episode_index": len(scenes), "task": demo.task, "seed": demo.seed,
                           "scene_params": demo.scene_params, "outcome": demo.outcome, "source": str(path)})
            k = t // 2
            checks.append(EpisodeCheck(
                length=t, task=text, plan=tuple(int(v) for v in frames["plan"][0]),
                label=tuple(int(v) for v in frames["label"][0]), sample_index=k,
                sample_state=frames["observation.state"][k].copy(), source=str(path)))
    finally:
        ds.finalize()
    with open(staging / SCENES_FILE, "w") as fh:
        fh.writelines(json.dumps(row) + "\n" for row in scenes)
    return checks


def read_scenes(root: Path | str) -> list[dict[str, Any]]:
    """Per-episode scene records of an exported dataset (``SCENES_FILE``), in episode order.

    Each: ``episode_index``, ``task``, ``seed`` (scene seed), ``scene_params`` (the randomised
    values, from which ``prl.shapes`` rebuilds the tool and object meshes), ``outcome``, ``source``.
    """
    path = Path(root) / SCENES_FILE
    if not path.is_file():
        raise FileNotFoundError(f"dataset at {str(root)!r} has no scene records ({SCENES_FILE} is missing)")
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    if [r.get("episode_index") for r in rows] != list(range(len(rows))):
        raise ValueError(f"{str(path)!r}: episode_index values are not 0..{len(rows) - 1}")
    return rows


# ----------------------------------------------------------------------------- validation


def validate_lerobot(root: Path | str, repo_id: str = DEFAULT_REPO_ID, *,
                     expected: Sequence[EpisodeCheck] | None = None, drop_cache: bool = False) -> ExportReport:
    """Reload the dataset at ``root`` with ``LeRobotDataset`` (offline) and check it; raise ExportError.

    Always checked: format v3.0, every ``FEATURES`` entry with its dtype and shape, episode
    indices 0..N-1, per-episode lengths in the metadata equal to the frames in the data,
    contiguous frame ranges and global indices, total frames, one task sentence per episode,
    plan/label/x_manip constant within each episode, one scene record per episode (``SCENES_FILE``). With ``expected`` (one per episode, in
    order): episode count, lengths, task sentences, plan and label, and the reloaded
    ``observation.state`` (and plan) of one frame per episode read through ``dataset[i]``.

    Loading makes ``datasets`` write an Arrow copy of the parquet files into its cache
    (``~/.cache/huggingface/datasets/parquet``, about 5x the dataset size); ``drop_cache``
    removes the copies this load used (the export does so for its staging directory).
    """
    t0 = time.perf_counter()
    root = Path(root)
    _precheck_files(root)
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    try:
        ds = LeRobotDataset(repo_id, root=root)
    except Exception as exc:
        raise ExportError(f"LeRobot could not load the dataset at {str(root)!r}: {type(exc).__name__}: {exc}") from exc
    try:
        return _validate_loaded(ds, root, repo_id, expected, t0)
    finally:
        if drop_cache:
            drop_datasets_cache(ds)


def _validate_loaded(ds: Any, root: Path, repo_id: str, expected: Sequence[EpisodeCheck] | None,
                     t0: float) -> ExportReport:
    """The checks of :func:`validate_lerobot` on a loaded dataset."""

    def fail(msg: str) -> NoReturn:
        raise ExportError(f"dataset at {str(root)!r}: {msg}")

    meta = ds.meta
    version = getattr(meta.info, "codebase_version", None)
    if version != CODEBASE_VERSION:
        fail(f"codebase_version {version!r}, expected {CODEBASE_VERSION!r}")
    for name, spec in FEATURES.items():
        got = meta.features.get(name)
        if got is None:
            fail(f"feature {name!r} is missing")
        if got["dtype"] != spec["dtype"] or tuple(got["shape"]) != tuple(spec["shape"]):
            fail(f"feature {name!r} is {got['dtype']}{tuple(got['shape'])}, expected {spec['dtype']}{spec['shape']}")

    n_eps = meta.total_episodes
    eps = meta.episodes
    ep_index = np.asarray(eps["episode_index"], dtype=np.int64)
    if not np.array_equal(ep_index, np.arange(n_eps)):
        fail(f"episode indices are {ep_index.tolist()[:10]}..., expected 0..{n_eps - 1}")
    lengths = np.asarray(eps["length"], dtype=np.int64)
    starts = np.asarray(eps["dataset_from_index"], dtype=np.int64)
    ends = np.asarray(eps["dataset_to_index"], dtype=np.int64)
    bounds = np.concatenate([[0], np.cumsum(lengths)])
    if np.any(lengths <= 0) or not np.array_equal(starts, bounds[:-1]) or not np.array_equal(ends, bounds[1:]):
        fail("episode frame ranges are not contiguous or do not match the episode lengths")
    n_frames = int(bounds[-1])
    if meta.total_frames != n_frames or len(ds) != n_frames:
        fail(f"total frames: info says {meta.total_frames}, dataset has {len(ds)}, episodes sum to {n_frames}")

    table = ds.hf_dataset.data
    col_ep = table.column("episode_index").to_numpy()
    if not np.array_equal(col_ep, np.repeat(np.arange(n_eps), lengths)):
        fail("per-frame episode_index does not match the episode lengths (counts or order differ)")
    if not np.array_equal(table.column("index").to_numpy(), np.arange(n_frames)):
        fail("global frame index is not 0..N-1")
    frame_index = table.column("frame_index").to_numpy()
    if not np.array_equal(frame_index, np.arange(n_frames) - np.repeat(starts, lengths)):
        fail("frame_index does not restart at 0 in every episode")

    tasks: list[str] = []
    for i, ep_tasks in enumerate(eps["tasks"]):
        if len(ep_tasks) != 1:
            fail(f"episode {i} has {len(ep_tasks)} task sentences, expected 1: {ep_tasks!r}")
        tasks.append(str(ep_tasks[0]))
    task_of_index = {int(v): str(k) for k, v in zip(meta.tasks.index, meta.tasks["task_index"], strict=True)}
    col_task = table.column("task_index").to_numpy()
    if any(task_of_index.get(int(col_task[s])) != tasks[i] for i, s in enumerate(starts)):
        fail("frame task_index does not map to the episode's task sentence")

    per_ep = {}
    for name in _PER_EPISODE:
        width = FEATURES[name]["shape"][0]
        values = table.column(name).combine_chunks().flatten().to_numpy().reshape(n_frames, width)
        if not np.all(values == np.repeat(values[starts], lengths, axis=0)):
            fail(f"{name!r} is not constant within every episode")
        per_ep[name] = values[starts]
    n_labelled = int(np.sum(np.any(per_ep["label"] != NO_LABEL, axis=1)))
    try:
        scenes = read_scenes(root)
    except (FileNotFoundError, ValueError) as exc:
        fail(str(exc))
    if len(scenes) != n_eps:
        fail(f"{SCENES_FILE} has {len(scenes)} scene records for {n_eps} episodes")

    if expected is not None:
        expected = list(expected)
        if len(expected) != n_eps:
            fail(f"{n_eps} episodes, expected {len(expected)}")
        for i, exp in enumerate(expected):
            where = f"episode {i} ({exp.source or 'demo'})"
            if lengths[i] != exp.length:
                fail(f"{where} has {lengths[i]} frames, the demo {exp.length}")
            if tasks[i] != exp.task:
                fail(f"{where} has task {tasks[i]!r}, the demo {exp.task!r}")
            if scenes[i]["source"] != exp.source:
                fail(f"{where}: scene record is of {scenes[i]['source']!r}")
            if tuple(per_ep["plan"][i].tolist()) != exp.plan:
                fail(f"{where} has plan {per_ep['plan'][i].tolist()}, the demo {list(exp.plan)}")
            if tuple(per_ep["label"][i].tolist()) != exp.label:
                fail(f"{where} has label {per_ep['label'][i].tolist()}, expected {list(exp.label)}")
            item = ds[int(starts[i]) + exp.sample_index]
            if int(item["episode_index"]) != i or int(item["frame_index"]) != exp.sample_index:
                fail(f"{where}: dataset[{int(starts[i]) + exp.sample_index}] is not its frame {exp.sample_index}")
            if item["plan"].tolist() != list(exp.plan):
                fail(f"{where}: frame {exp.sample_index} has plan {item['plan'].tolist()}, the demo {list(exp.plan)}")
            if item["task"] != exp.task:
                fail(f"{where}: frame {exp.sample_index} has task {item['task']!r}")
            state = item["observation.state"].numpy()
            if not np.array_equal(state, exp.sample_state):
                fail(f"{where}: observation.state of frame {exp.sample_index} differs from the demo "
                     f"(max abs diff {float(np.max(np.abs(state - exp.sample_state))):.3g})")

    return ExportReport(
        root=root, repo_id=repo_id, fps=int(meta.fps), n_episodes=int(n_eps), n_frames=n_frames,
        episode_lengths=tuple(int(v) for v in lengths), tasks=tuple(tasks), n_labelled=n_labelled,
        size_bytes=_tree_size(root), seconds=time.perf_counter() - t0, checked_against_demos=expected is not None,
    )


@contextlib.contextmanager
def _quiet_fast_writes(fast: bool = True) -> Iterator[None]:
    """Within the block: no ``datasets`` progress bars; with ``fast``, no per-frame image embedding.

    lerobot 0.6's ``DatasetWriter._save_episode_data`` runs ``embed_images`` on every episode,
    a row-by-row ``datasets.map`` (~6 ms a frame) that changes nothing when no feature is an
    image; with ``fast`` the writer's reference to it is replaced by the identity for the
    block (only when ``FEATURES`` holds no image or video). Both are restored afterwards.
    """
    import datasets

    bars = datasets.is_progress_bar_enabled()
    datasets.disable_progress_bars()
    patched = None
    if fast and all(spec["dtype"] not in ("image", "video") for spec in FEATURES.values()):
        from lerobot.datasets import dataset_writer

        if callable(getattr(dataset_writer, "embed_images", None)):
            patched = dataset_writer.embed_images
            dataset_writer.embed_images = lambda dataset: dataset
    try:
        yield
    finally:
        if patched is not None:
            from lerobot.datasets import dataset_writer

            dataset_writer.embed_images = patched
        if bars:
            datasets.enable_progress_bars()


def drop_datasets_cache(ds: Any) -> None:
    """Delete the ``datasets`` Arrow cache directories that loading ``ds`` created or used."""
    import datasets

    cache_root = Path(datasets.config.HF_DATASETS_CACHE).resolve()
    files = []
    for hf in (getattr(ds.reader, "hf_dataset", None), getattr(ds.meta, "episodes", None)):
        files += [Path(c["filename"]) for c in (getattr(hf, "cache_files", None) or [])]
    for d in {f.resolve().parent for f in files}:  # <builder>/<config>/<version>/<fingerprint>/
        if cache_root not in d.parents:
            continue
        shutil.rmtree(d, ignore_errors=True)
        locks = [*d.parent.glob(f"{d.name}*.lock"),
                 *cache_root.glob(f"*_{d.parent.parent.name}_{d.parent.name}_{d.name}.lock")]
        for lock in locks:
            lock.unlink(missing_ok=True)
        for parent in (d.parent, d.parent.parent):  # drop now-empty version / config directories
            with contextlib.suppress(OSError):
                parent.rmdir()


def _precheck_files(root: Path) -> None:
    """Fail (ExportError) unless ``root`` holds a complete local v3.0 dataset.

    lerobot would otherwise create ``root`` and try to download what is missing from the Hub.
    """
    import pyarrow.parquet as pq

    if not root.is_dir():
        raise ExportError(f"no dataset at {str(root)!r} (not a directory)")
    info_path = root / "meta" / "info.json"
    try:
        info = json.loads(info_path.read_text())
    except (OSError, ValueError) as exc:
        raise ExportError(f"no readable {str(info_path)!r}: {exc}") from exc
    if info.get("codebase_version") != CODEBASE_VERSION:
        raise ExportError(f"{str(info_path)!r}: codebase_version {info.get('codebase_version')!r}, "
                          f"expected {CODEBASE_VERSION!r}")
    if not (root / "meta" / "tasks.parquet").is_file():
        raise ExportError(f"{str(root / 'meta' / 'tasks.parquet')!r} is missing")
    if not sorted((root / "meta" / "episodes").glob("*/*.parquet")):
        raise ExportError(f"no episode metadata under {str(root / 'meta' / 'episodes')!r}")
    data_files = sorted((root / "data").glob("*/*.parquet"))
    if not data_files:
        raise ExportError(f"no data files under {str(root / 'data')!r}")
    seen: set[int] = set()
    for f in data_files:
        try:
            seen.update(pq.read_table(f, columns=["episode_index"]).column(0).to_numpy().tolist())
        except Exception as exc:
            raise ExportError(f"data file {str(f)!r} is unreadable: {exc}") from exc
    n = int(info.get("total_episodes", -1))
    if n <= 0 or not set(range(n)) <= seen:
        raise ExportError(f"data files under {str(root / 'data')!r} lack episodes of the {n} in info.json")


# ----------------------------------------------------------------------------- files


def _check_destination(root: Path) -> None:
    """Raise unless ``root`` can be (re)placed: parent creatable and writable, root a dataset or absent."""
    if root.exists() or root.is_symlink():
        if not root.is_dir() or root.is_symlink():
            raise NotADirectoryError(f"destination {str(root)!r} exists and is not a directory")
        if any(root.iterdir()) and not (root / "meta" / "info.json").is_file():
            raise ValueError(f"destination {str(root)!r} exists, is not empty and is not a LeRobot dataset; "
                             "refusing to replace it")
    probe = root.parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise NotADirectoryError(f"destination {str(root)!r}: {str(probe)!r} is not a directory")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise PermissionError(f"destination {str(root)!r} is not writable ({str(probe)!r} denies writing)")
    try:
        root.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PermissionError(f"destination {str(root)!r} is not writable: {exc}") from exc


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _recover_stale(root: Path) -> None:
    """Clean up after a killed export of ``root``: drop its staging dir, restore or drop a set-aside root."""
    for kind in ("staging", "old"):
        for d in root.parent.glob(f".{root.name}.{kind}-*"):
            try:
                pid = int(d.name.rsplit("-", 1)[1])
            except ValueError:
                continue
            if pid == os.getpid() or _pid_alive(pid):
                continue
            if kind == "old" and not (root / "meta" / "info.json").is_file():
                # killed between moving the old dataset aside and the new one in: put it back
                if root.is_dir() and not root.is_symlink() and not any(root.iterdir()):
                    root.rmdir()
                if not root.exists():
                    os.rename(d, root)
            else:
                shutil.rmtree(d, ignore_errors=True)


def _rename_exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False where unsupported."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP):
        return False
    raise OSError(err, f"swapping {str(a)!r} and {str(b)!r} failed: {os.strerror(err)}")


def _fsync_dir(d: Path) -> None:
    fd = os.open(d, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _move_into_place(staging: Path, root: Path) -> None:
    """Make ``staging`` the dataset at ``root``; an old dataset there is removed only once replaced."""
    if not root.exists():
        os.rename(staging, root)
    elif _rename_exchange(staging, root):
        shutil.rmtree(staging)  # now holds the old dataset
    else:
        old = root.parent / f".{root.name}.old-{os.getpid()}"
        os.rename(root, old)
        try:
            os.rename(staging, root)
        except BaseException:
            os.rename(old, root)
            raise
        shutil.rmtree(old)
    _fsync_dir(root.parent)


def _tree_size(root: Path) -> int:
    return sum(f.stat().st_size for f in Path(root).rglob("*") if f.is_file())


def dataset_digest(root: Path) -> str:
    """A short digest of a dataset's files (names and bytes), for tracking which data a run used."""
    import hashlib

    h = hashlib.sha256()
    for path in sorted(p for p in Path(root).rglob("*") if p.is_file()):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]
