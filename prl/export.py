"""LeRobot dataset export (format v3.0) of saved demonstrations (docs/design.md "Export").

One episode per demonstration (``prl.demo.Demo``), one frame per recorded step, the episode's
task being the demo's task sentence; the frame layout is ``prl.export_schema.FEATURES``. The
dataset is written with the ``lerobot`` package (``LeRobotDataset.create`` -> ``add_frame`` ->
``save_episode`` -> ``finalize``) into a staging directory next to the destination, reloaded with
``LeRobotDataset(repo_id, root=staging)`` and validated against the demos
(``prl.export_check.validate_lerobot``), and only then moved into place (``prl.dataset_files``): a
failed or killed export never leaves a broken dataset where a good one was. :func:`export_key` and
:func:`reusable_export` let an identical earlier export stand instead of being rewritten.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from prl.dataset_files import check_destination, move_into_place, recover_stale, staging_path, tree_size
from prl.demo import load_demo
from prl.export_check import EpisodeCheck, validate_lerobot
from prl.export_schema import (
    DEFAULT_FPS,
    DEFAULT_REPO_ID,
    EXPORT_KEY_FILE,
    FEATURES,
    ROBOT_TYPE,
    SCENES_FILE,
    ExportReport,
    as_label,
    episode_frames,
    lerobot_features,
)


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
    reloaded with ``LeRobotDataset`` and validated against the demos
    (``prl.export_check.validate_lerobot``); then it replaces ``root`` atomically
    (``prl.dataset_files.move_into_place``: ``renameat2(RENAME_EXCHANGE)`` where supported, else
    old-aside / new-in / old-removed). On any failure the staging directory is removed and an
    existing dataset at ``root`` is left untouched. Leftovers of a killed export (a staging or
    set-aside directory whose process is gone) are cleaned up or restored on the next export
    (``prl.dataset_files.recover_stale``).

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
    check_destination(root)
    recover_stale(root)
    staging = staging_path(root)
    if staging.exists():
        shutil.rmtree(staging)
    try:
        with _quiet_fast_writes(fast=fast_writes):
            checks = _write(paths, staging, repo_id, fps, per_episode_label)
            if key is not None:
                (staging / EXPORT_KEY_FILE).write_text(key + "\n")
            report = validate_lerobot(staging, repo_id, expected=checks, drop_cache=True)
        move_into_place(staging, root)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return ExportReport(
        root=root, repo_id=repo_id, fps=report.fps, n_episodes=report.n_episodes, n_frames=report.n_frames,
        episode_lengths=report.episode_lengths, tasks=report.tasks, n_labelled=report.n_labelled,
        size_bytes=tree_size(root), seconds=time.perf_counter() - t0, checked_against_demos=True,
    )


def export_key(demo_paths: Sequence[Path | str], labels: Mapping[str, Sequence[int]] | None, repo_id: str,
               fps: int, code_version: str) -> str:
    """A digest of everything an export is made from: each demo file's name and bytes, in order, its
    label (looked up by the path as given), ``repo_id``, ``fps`` and ``code_version``. Demo files are
    written once and never change, so an equal key means an equal dataset."""
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

    The dataset is still reloaded with ``LeRobotDataset`` and checked
    (``prl.export_check.validate_lerobot``), so a damaged one raises ExportError instead of being reused."""
    t0 = time.perf_counter()
    root = Path(os.path.abspath(root))
    stored = root / EXPORT_KEY_FILE
    if not stored.is_file() or stored.read_text().strip() != key:
        return None
    report = validate_lerobot(root, repo_id, drop_cache=True)
    return replace(report, size_bytes=tree_size(root), seconds=time.perf_counter() - t0, reused=True)


def _label_for(path: Path, seed: int, labels: Mapping[Any, Any] | None) -> np.ndarray | None:
    if not labels:
        return None
    for key in (path, str(path), path.resolve(), str(path.resolve()), seed):
        if key in labels:
            return as_label(labels[key])
    return None


def _load(path: Path) -> Any:
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
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # heavy (torch, datasets): only when writing

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


@contextlib.contextmanager
def _quiet_fast_writes(fast: bool = True) -> Iterator[None]:
    """Within the block: no ``datasets`` progress bars; with ``fast``, no per-frame image embedding.

    lerobot 0.6's ``DatasetWriter._save_episode_data`` runs ``embed_images`` on every episode,
    a row-by-row ``datasets.map`` (~6 ms a frame) that changes nothing when no feature is an
    image; with ``fast`` the writer's reference to it is replaced by the identity for the
    block (only when ``FEATURES`` holds no image or video). Both are restored afterwards.
    """
    import datasets  # heavy (pyarrow, pandas): only around a write

    bars = datasets.is_progress_bar_enabled()
    datasets.disable_progress_bars()
    patched = None
    if fast and all(spec["dtype"] not in ("image", "video") for spec in FEATURES.values()):
        from lerobot.datasets import dataset_writer  # heavy: only to patch it for the block

        if callable(getattr(dataset_writer, "embed_images", None)):
            patched = dataset_writer.embed_images
            dataset_writer.embed_images = lambda dataset: dataset
    try:
        yield
    finally:
        if patched is not None:
            from lerobot.datasets import dataset_writer  # already loaded above: the same module

            dataset_writer.embed_images = patched
        if bars:
            datasets.enable_progress_bars()
