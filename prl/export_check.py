"""Checks of an exported LeRobot v3.0 dataset on reload (the contract is ``prl.export_schema``).

:func:`validate_lerobot` reloads a dataset with ``LeRobotDataset`` and checks it against
``FEATURES`` and the lerobot metadata; given one :class:`EpisodeCheck` per demo (from the writer,
``prl.export``) it also compares every episode with the demo it came from.

Reloading is offline: ``LeRobotDataset(repo_id, root=...)`` reads a complete local root without
touching the Hub, but falls back to a Hub download when local files are missing (and creates
``root`` if it does not exist). :func:`validate_lerobot` therefore checks the files on disk with
pyarrow first and only then hands the root to lerobot.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from prl.dataset_files import tree_size
from prl.export_schema import (
    CODEBASE_VERSION,
    DEFAULT_REPO_ID,
    FEATURES,
    NO_LABEL,
    OPTIONAL_FEATURES,
    PER_EPISODE,
    SCENES_FILE,
    VIDEO_CAMERAS,
    ExportError,
    ExportReport,
    VideoSpec,
    read_scenes,
    video_key,
)


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



def validate_lerobot(root: Path | str, repo_id: str = DEFAULT_REPO_ID, *,
                     expected: Sequence[EpisodeCheck] | None = None, video: VideoSpec | None = None,
                     drop_cache: bool = False) -> ExportReport:
    """Reload the dataset at ``root`` with ``LeRobotDataset`` (offline) and check it; raise ExportError.

    Always checked: format v3.0, every ``FEATURES`` entry with its dtype and shape, episode
    indices 0..N-1, per-episode lengths in the metadata equal to the frames in the data,
    contiguous frame ranges and global indices, total frames, one task sentence per episode,
    plan/label/x_manip constant within each episode, one scene record per episode (``SCENES_FILE``). With ``expected`` (one per episode, in
    order): episode count, lengths, task sentences, plan and label, and the reloaded
    ``observation.state`` (and plan) of one frame per episode read through ``dataset[i]``. With
    ``video``: each camera's video feature (``VideoSpec.features``: dtype, shape), its codec and
    fps in the metadata, and, with ``expected``, that frame's pictures decoded at the spec's size.

    Loading makes ``datasets`` write an Arrow copy of the parquet files into its cache
    (``~/.cache/huggingface/datasets/parquet``, about 5x the dataset size); ``drop_cache``
    removes the copies this load used (the export does so for its staging directory).
    """
    t0 = time.perf_counter()
    root = Path(root)
    ds = load_local(root, repo_id)
    try:
        return _validate_loaded(ds, root, repo_id, expected, video, t0)
    finally:
        if drop_cache:
            drop_datasets_cache(ds)


def load_local(root: Path, repo_id: str = DEFAULT_REPO_ID) -> Any:
    """The dataset at ``root`` as lerobot's ``LeRobotDataset``, offline: ExportError (never a Hub download) when
    ``root`` is no complete local v3.0 dataset or lerobot cannot load it."""
    _precheck_files(root)
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # heavy (torch, datasets): only to reload

    try:
        return LeRobotDataset(repo_id, root=root)
    except Exception as exc:
        raise ExportError(f"LeRobot could not load the dataset at {str(root)!r}: {type(exc).__name__}: {exc}") from exc


def _validate_loaded(ds: Any, root: Path, repo_id: str, expected: Sequence[EpisodeCheck] | None,
                     video: VideoSpec | None, t0: float) -> ExportReport:
    """The checks of :func:`validate_lerobot` on a loaded dataset."""

    def fail(msg: str) -> NoReturn:
        raise ExportError(f"dataset at {str(root)!r}: {msg}")

    meta = ds.meta
    version = getattr(meta.info, "codebase_version", None)
    if version != CODEBASE_VERSION:
        fail(f"codebase_version {version!r}, expected {CODEBASE_VERSION!r}")
    for name, spec in FEATURES.items():
        got = meta.features.get(name)
        if got is None and name in OPTIONAL_FEATURES:
            continue  # a dataset exported before the feature existed (what needs it says so: require_feature)
        if got is None:
            fail(f"feature {name!r} is missing")
        if got["dtype"] != spec["dtype"] or tuple(got["shape"]) != tuple(spec["shape"]):
            fail(f"feature {name!r} is {got['dtype']}{tuple(got['shape'])}, expected {spec['dtype']}{spec['shape']}")

    codec = _check_video_features(meta, video, fail)
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
    for name in PER_EPISODE:
        width = FEATURES[name]["shape"][0]
        values = table.column(name).combine_chunks().flatten().to_numpy().reshape(n_frames, width)
        if not np.all(values == np.repeat(values[starts], lengths, axis=0)):
            fail(f"{name!r} is not constant within every episode")
        per_ep[name] = values[starts]
    for name in meta.video_keys:  # every video holds one frame per dataset frame of each episode
        spans = (np.asarray(eps[f"videos/{name}/to_timestamp"], dtype=float)
                 - np.asarray(eps[f"videos/{name}/from_timestamp"], dtype=float)) * meta.fps
        if not np.allclose(spans, lengths, atol=0.5):
            fail(f"video {name!r} spans {np.round(spans).astype(int).tolist()[:10]} frames per episode, the "
                 f"episodes have {lengths.tolist()[:10]}")
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
            for name, spec in (video.features() if video is not None else {}).items():
                h, w, c = spec["shape"]
                if tuple(item[name].shape) != (c, h, w):
                    fail(f"{where}: frame {exp.sample_index} of {name!r} decodes to {tuple(item[name].shape)}, "
                         f"expected {(c, h, w)}")
            state = item["observation.state"].numpy()
            if not np.array_equal(state, exp.sample_state):
                fail(f"{where}: observation.state of frame {exp.sample_index} differs from the demo "
                     f"(max abs diff {float(np.max(np.abs(state - exp.sample_state))):.3g})")

    return ExportReport(
        root=root, repo_id=repo_id, fps=int(meta.fps), n_episodes=int(n_eps), n_frames=n_frames,
        episode_lengths=tuple(int(v) for v in lengths), tasks=tuple(tasks), n_labelled=n_labelled,
        size_bytes=tree_size(root), seconds=time.perf_counter() - t0, checked_against_demos=expected is not None,
        video_codec=codec,
    )


def _check_video_features(meta: Any, video: VideoSpec | None, fail: Any) -> str | None:
    """With ``video``: every camera's feature as the spec says, with a codec and the dataset's fps in its
    metadata; returns the codec (of the first camera's video), or None without video features."""
    if video is not None:
        for name, spec in video.features().items():
            got = meta.features.get(name)
            if got is None:
                fail(f"video feature {name!r} is missing")
            if got["dtype"] != "video" or tuple(got["shape"]) != tuple(spec["shape"]):
                fail(f"feature {name!r} is {got['dtype']}{tuple(got['shape'])}, expected video{spec['shape']}")
            info = got.get("info") or {}
            if not info.get("video.codec"):
                fail(f"video feature {name!r} has no codec in meta/info.json")
            if int(info.get("video.fps", -1)) != int(meta.fps):
                fail(f"video feature {name!r} is at {info.get('video.fps')} fps, the dataset at {meta.fps}")
    first = meta.features.get(video_key(VIDEO_CAMERAS[0]))
    return None if first is None else (first.get("info") or {}).get("video.codec")


def drop_datasets_cache(ds: Any) -> None:
    """Delete the ``datasets`` Arrow cache directories that loading ``ds`` created or used."""
    import datasets  # heavy (pyarrow, pandas): only where a dataset was loaded

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
    import pyarrow.parquet as pq  # heavy: only when a dataset is checked

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
    for name, spec in (info.get("features") or {}).items():
        if spec.get("dtype") == "video" and not sorted((root / "videos" / name).glob("*/*.mp4")):
            raise ExportError(f"no video files of {name!r} under {str(root / 'videos' / name)!r}")

