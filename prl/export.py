"""LeRobot dataset export (format v3.0) of saved demonstrations (docs/guide/design.md "Export").

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
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from prl.dataset_files import check_destination, move_into_place, recover_stale, staging_path, tree_size
from prl.demo import Demo, load_demo
from prl.episode_stats import fast_episode_stats
from prl.export_check import EpisodeCheck, validate_lerobot
from prl.export_merge import export_parts, part_episode_written, step, write_parallel
from prl.export_schema import (
    DEFAULT_FPS,
    DEFAULT_REPO_ID,
    EXPORT_KEY_FILE,
    FEATURES,
    ROBOT_TYPE,
    SCENES_FILE,
    VIDEO_CAMERAS,
    ExportReport,
    VideoSpec,
    as_label,
    episode_frames,
    lerobot_features,
    video_key,
)

RenderImages = Callable[[Demo, Sequence[int], str], Mapping[str, np.ndarray]]
"""``render_images(demo, records, source)``: ``{camera: (len(records), H, W, 3) uint8}`` pictures of the demo at
those records, one per camera of ``VIDEO_CAMERAS`` (``envs.video.DemoRenderer``; ``source`` names the file in
errors)."""

STREAM_QUEUE_FRAMES = 100_000
"""Frames per camera lerobot's streaming encoder may hold back; more than an episode has, so none is dropped."""
VIDEO_CODECS: tuple[str, ...] = ("libsvtav1", "h264", "libaom-av1")
"""Encoders tried for the cameras' video, in order: lerobot's default (SVT-AV1), then what works elsewhere."""


def export_lerobot(
    demo_paths: Sequence[Path | str],
    root: Path | str,
    repo_id: str = DEFAULT_REPO_ID,
    fps: int = DEFAULT_FPS,
    per_episode_label: Mapping[Any, Sequence[int] | np.ndarray] | None = None,
    *,
    video: VideoSpec | None = None,
    render_images: RenderImages | None = None,
    fast_writes: bool = True,
    key: str | None = None,
    workers: int = 1,
) -> ExportReport:
    """Export demos (``prl.demo`` ``.npz`` files) as a LeRobot v3.0 dataset at ``root``.

    Episode ``i`` is ``demo_paths[i]``. ``per_episode_label`` maps a demo's path (as given, as
    string or resolved) or its scene seed to its (6,) recovered physical-law label; episodes
    without one get ``NO_LABEL`` s. With ``video`` (a :class:`VideoSpec`), ``render_images`` draws
    each demo's camera pictures at ``video.records`` (this module never renders: it is pure), and
    every camera is written as a video feature through lerobot (``use_videos=True``) with the first
    encoder of ``VIDEO_CODECS`` that this machine's PyAV has (:func:`video_encoder`; lerobot records
    the codec in ``meta/info.json``). ``fast_writes`` skips lerobot's per-frame image-embedding
    pass, a no-op without image features that costs ~6 ms a frame, and computes lerobot's
    per-episode statistics in fewer numpy calls (``prl.episode_stats``; see :func:`_quiet_fast_writes`),
    writes ``meta/stats.json`` once instead of after every episode, without hashing each episode's
    table for a fingerprint nothing keeps (:func:`_lean_writes`), and, without video, hands each episode to
    lerobot whole instead of frame by frame (:func:`_episode_buffer`); the files are the same.
    ``key`` (from :func:`export_key`) is written to ``EXPORT_KEY_FILE`` so that a later identical
    export can be skipped with :func:`reusable_export`.

    ``workers`` > 1 (without video, and with at least ``prl.export_merge.PARALLEL_MIN_EPISODES`` episodes per
    worker) writes contiguous parts of ``demo_paths`` as datasets of their own in that many processes and merges
    them in order with lerobot's ``aggregate_datasets`` (``prl.export_merge``): the same episodes, frames and
    statistics as one process writes (the statistics up to float rounding), in other parquet files.

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
    if video is not None and not isinstance(video, VideoSpec):
        raise TypeError(f"video must be a VideoSpec or None, got {video!r}")
    if video is not None and render_images is None:
        raise ValueError("video is set but render_images is None: the export needs something that draws the "
                         "cameras' pictures (envs.video.DemoRenderer)")
    if isinstance(fps, bool) or not isinstance(fps, int) or fps <= 0:
        raise ValueError(f"fps must be a positive integer, got {fps!r}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
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
            parts = export_parts(len(paths), workers if video is None else 1)
            if len(parts) > 1:
                checks = write_parallel(_write_part, [[paths[i] for i in part] for part in parts], staging,
                                        repo_id, fps, per_episode_label, fast_writes)
                video_seconds = 0.0
            else:
                with _lean_writes() if fast_writes else contextlib.nullcontext(), \
                        tqdm(total=len(paths), desc="export", unit="episode") as bar:
                    checks, video_seconds = _write(paths, staging, repo_id, fps, per_episode_label, video,
                                                   render_images, whole=fast_writes, on_episode=bar.update)
            if key is not None:
                (staging / EXPORT_KEY_FILE).write_text(key + "\n")
            with step(f"export: reloading the {len(checks):,} episodes with LeRobotDataset and checking them"):
                report = validate_lerobot(staging, repo_id, expected=checks, video=video, drop_cache=True)
        move_into_place(staging, root)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return replace(report, root=root, size_bytes=tree_size(root), seconds=time.perf_counter() - t0,
                   video_seconds=video_seconds)


def export_key(demo_paths: Sequence[Path | str], labels: Mapping[str, Sequence[int]] | None, repo_id: str,
               fps: int, code_version: str, video: VideoSpec | None = None) -> str:
    """A digest of everything an export is made from: each demo file's name and bytes, in order, its
    label (looked up by the path as given), ``repo_id``, ``fps``, the ``video`` settings and
    ``code_version``. Demo files are written once and never change, so an equal key means an equal
    dataset."""
    video_settings = [] if video is None else [[video.width, video.height, video.fps]]
    h = hashlib.sha256(json.dumps([repo_id, fps, code_version, *video_settings]).encode())
    for p in demo_paths:
        path = Path(p)
        label = None if labels is None else labels.get(str(p))
        h.update(json.dumps([path.name, None if label is None else [int(v) for v in label]]).encode())
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()[:20]


def reusable_export(root: Path | str, repo_id: str, key: str, video: VideoSpec | None = None) -> ExportReport | None:
    """The validated report of the dataset at ``root`` if it was exported with ``key``; else None.

    The dataset is still reloaded with ``LeRobotDataset`` and checked
    (``prl.export_check.validate_lerobot``), so a damaged one raises ExportError instead of being reused."""
    t0 = time.perf_counter()
    root = Path(os.path.abspath(root))
    stored = root / EXPORT_KEY_FILE
    if not stored.is_file() or stored.read_text().strip() != key:
        return None
    report = validate_lerobot(root, repo_id, video=video, drop_cache=True)
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


def video_encoder(codecs: Sequence[str] = VIDEO_CODECS) -> Any:
    """lerobot's ``RGBEncoderConfig`` for the first of ``codecs`` that this machine's PyAV can encode with
    (lerobot's other settings left at its defaults); ValueError naming every codec tried when none can."""
    from lerobot.configs.video import RGBEncoderConfig  # heavy (lerobot, av): only when writing video

    errors = []
    for codec in codecs:
        try:
            return RGBEncoderConfig(vcodec=codec)
        except (ValueError, ImportError) as exc:  # lerobot's "Unsupported video codec" / "Invalid vcodec"
            errors.append(f"{codec}: {exc}")
    raise ValueError("no video encoder works here; tried " + "; ".join(errors))


def _write(paths: list[Path], staging: Path, repo_id: str, fps: int, labels: Mapping[Any, Any] | None,
           video: VideoSpec | None, render_images: RenderImages | None, whole: bool = False,
           on_episode: Callable[[], Any] = lambda: None) -> tuple[list[EpisodeCheck], float]:
    """Write every demo as an episode into ``staging`` (create -> add_frame -> save_episode -> finalize; with
    ``whole`` and no video, each episode handed to ``save_episode`` at once, :func:`_episode_buffer`), calling
    ``on_episode()`` after each (a progress bar's); return the checks of the episodes and the seconds spent rendering
    pictures."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # heavy (torch, datasets): only when writing

    encoder = video_encoder() if video is not None else None
    # streaming: frames go straight to one encoder thread per camera, with no PNG round trip (0.73 s an
    # episode against 1.17 s encoding the PNGs afterwards, 1.27 s in lerobot's default forked processes);
    # lerobot drops a frame its queue cannot take, so the queue holds more than any episode has
    ds = LeRobotDataset.create(repo_id, fps=fps, features=lerobot_features(video), root=staging,
                               robot_type=ROBOT_TYPE, use_videos=video is not None, rgb_encoder=encoder,
                               streaming_encoding=video is not None, encoder_queue_maxsize=STREAM_QUEUE_FRAMES)
    checks: list[EpisodeCheck] = []
    scenes: list[dict[str, Any]] = []
    video_seconds = 0.0
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
            if video is not None:
                tv = time.perf_counter()
                frames.update(_camera_frames(demo, video, render_images, str(path)))
                video_seconds += time.perf_counter() - tv
            if whole and video is None:
                ds.save_episode(episode_data=_episode_buffer(ds, frames, text))
            else:  # lerobot's streaming encoder is fed frame by frame by add_frame
                for i in range(t):
                    ds.add_frame({**{name: a[i] for name, a in frames.items()}, "task": text})
                ds.save_episode()
            scenes.append({"episode_index": len(scenes), "task": demo.task, "seed": demo.seed,
                           "scene_params": demo.scene_params, "outcome": demo.outcome, "source": str(path),
                           "proposal_logp": demo.proposal_logp, "prior_logp": demo.prior_logp})
            k = t // 2
            checks.append(EpisodeCheck(
                length=t, task=text, plan=tuple(int(v) for v in frames["plan"][0]),
                label=tuple(int(v) for v in frames["label"][0]), sample_index=k,
                sample_state=frames["observation.state"][k].copy(), source=str(path)))
            on_episode()
    finally:
        ds.finalize()
    with open(staging / SCENES_FILE, "w") as fh:
        fh.writelines(json.dumps(row) + "\n" for row in scenes)
    return checks, video_seconds


def _episode_buffer(ds: Any, frames: dict[str, np.ndarray], text: str) -> dict[str, Any]:
    """The episode buffer lerobot's ``add_frame`` would gather from ``frames`` (``{feature: (T, ...) array}``), whole:
    for ``save_episode(episode_data=...)``, lerobot's way in for an episode recorded elsewhere.

    ``add_frame`` validates each frame's features against the dataset's (dtype and shape), appends them to lists and
    numbers the frames (``frame_index``, ``timestamp = frame_index / fps``); ``save_episode`` stacks the lists. Here
    the first frame is validated by lerobot's own ``validate_frame`` (every frame of an array has the first's dtype
    and shape) and the arrays are handed over whole: the same table, without 150 dictionary-building, validating
    calls an episode (``tests/prl/test_export.py`` compares the files with ``add_frame``'s)."""
    from lerobot.datasets.feature_utils import validate_frame  # heavy (lerobot): loaded by the writer already

    t = int(frames["stage"].shape[0])
    validate_frame({**{name: a[0] for name, a in frames.items()}, "task": text}, ds.features)
    if any(a.shape[0] != t for a in frames.values()):
        raise ValueError(f"episode features of different lengths: { {n: a.shape[0] for n, a in frames.items()} }")
    index = np.arange(t)
    return {**{key: [] for key in ds.features}, **frames, "size": t, "task": [text] * t, "frame_index": index,
            "timestamp": index / ds.fps, "episode_index": ds.meta.total_episodes}  # save_episode fills index, task_index


def _write_part(paths: list[Path], root: Path, repo_id: str, fps: int, labels: Mapping[Any, Any] | None,
                fast: bool) -> list[EpisodeCheck]:
    """One worker process's part of ``prl.export_merge.write_parallel``: ``paths`` written as a dataset of its own at
    ``root``; returns their checks."""
    with _quiet_fast_writes(fast=fast), _lean_writes() if fast else contextlib.nullcontext():
        checks, _ = _write(paths, root, repo_id, fps, labels, None, None, whole=fast, on_episode=part_episode_written)
    return checks


def _camera_frames(demo: Demo, video: VideoSpec, render_images: RenderImages, source: str) -> dict[str, np.ndarray]:
    """``{video feature: (T, H, W, 3) uint8}``: the demo's pictures at ``video.records``, each held until the next."""
    t = int(np.asarray(demo.stage).shape[0])
    pictures = render_images(demo, video.records(t).tolist(), source)
    if set(pictures) != set(VIDEO_CAMERAS):
        raise ValueError(f"demo file {source!r}: pictures of cameras {sorted(pictures)}, expected {list(VIDEO_CAMERAS)}")
    try:
        return {video_key(cam): video.expand(pictures[cam], t) for cam in VIDEO_CAMERAS}
    except ValueError as exc:
        raise ValueError(f"demo file {source!r}: {exc}") from exc


@contextlib.contextmanager
def _lean_writes() -> Iterator[None]:
    """Within the block, three things lerobot 0.6 does on every ``save_episode`` are done once or faster. The first
    two keep nothing that a file holds before the last episode (cProfile of 60 hammer demos, 2026-12-04: 0.09 s and
    0.09 s of a 0.6 s ``save_episode``):

    - ``meta/stats.json``: the running statistics of all episodes so far are serialised and rewritten after every
      episode (``LeRobotDatasetMetadata.save_episode`` -> ``write_stats``). Here each call only keeps its
      arguments, and the last ones are written when the block ends normally; the statistics themselves are still
      aggregated episode by episode by lerobot, so the file is the one its last rewrite would leave. On an error the
      block writes nothing (the export discards its staging directory).
    - ``datasets``' fingerprint of each episode's in-memory table (a dill hash of all its values, in
      ``Dataset.__init__``): the writer only turns the table into a parquet row group, whose metadata holds the
      features and no fingerprint, and no cache file is made from it. Here the fingerprint is a random one, as
      ``datasets`` itself uses when a transform cannot be hashed.

    and the third is the same work done faster:

    - ``datasets``' encoding of each episode's columns (``Dataset.from_dict``: every frame's value encoded and
      typed one by one in Python, 34 ms of an episode of 150 frames, 2026-12-06): here the episode's numpy columns
      are handed to it as Arrow arrays of their features' types (:func:`arrow_columns`), which ``from_dict`` takes
      as they are; the table is the same, value for value and schema for schema.

    Only for writing (``_write``): the reload and validation run with ``datasets`` as it is.
    """
    import datasets.arrow_dataset  # heavy (pyarrow, pandas): only around a write
    from datasets.fingerprint import generate_random_fingerprint
    from lerobot.datasets import dataset_metadata  # heavy: only to patch it for the block

    table_class = datasets.arrow_dataset.Dataset
    from_dict = table_class.__dict__["from_dict"]  # the classmethod itself, to put back as it was
    saved = dataset_metadata.write_stats, datasets.arrow_dataset.generate_fingerprint, from_dict
    last: list[tuple[Any, Any]] = []

    def keep_last(stats: Any, root: Any) -> None:
        last[:] = [(stats, root)]

    def from_arrow_columns(cls: Any, mapping: Any, features: Any = None, *args: Any, **kwargs: Any) -> Any:
        columns = arrow_columns(mapping, features) if features is not None else mapping
        return from_dict.__func__(cls, columns, features, *args, **kwargs)

    dataset_metadata.write_stats = keep_last
    datasets.arrow_dataset.generate_fingerprint = lambda dataset: generate_random_fingerprint()
    table_class.from_dict = classmethod(from_arrow_columns)
    try:
        yield
    finally:
        dataset_metadata.write_stats, datasets.arrow_dataset.generate_fingerprint, table_class.from_dict = saved
    for stats, root in last:  # reached only when the block ended without an error
        saved[0](stats, root)


def arrow_columns(mapping: Mapping[str, Any], features: Any) -> dict[str, Any]:
    """``mapping`` (``{column: values}``, as for ``datasets.Dataset.from_dict``) with each numpy column whose feature
    is a number or a fixed-length list of numbers turned into an Arrow array of that feature's type; other columns
    are left as they are, for ``datasets`` to encode. ``features``: the ``datasets.Features`` of the columns.

    A ``(T,)`` or ``(T, 1)`` array becomes ``T`` numbers, a ``(T, n)`` array ``T`` lists of ``n``; the values are
    cast as Arrow casts (float64 -> float32 rounded to nearest, as ``datasets`` does). An array of another shape is
    an error naming its column."""
    import pyarrow as pa  # heavy: only around a write

    schema = features.arrow_schema
    out = dict(mapping)
    for name, values in mapping.items():
        if not isinstance(values, np.ndarray) or values.dtype.kind not in "biuf" or name not in schema.names:
            continue
        kind = schema.field(name).type
        item = kind.value_type if pa.types.is_fixed_size_list(kind) else kind
        if not (pa.types.is_integer(item) or pa.types.is_floating(item) or pa.types.is_boolean(item)):
            continue
        size = kind.list_size if pa.types.is_fixed_size_list(kind) else 1
        if values.ndim not in (1, 2) or values.size != values.shape[0] * size:
            raise ValueError(f"column {name!r}: values of shape {values.shape} for a feature of {size} per frame")
        flat = pa.array(np.ascontiguousarray(values).reshape(-1), type=item)
        out[name] = pa.FixedSizeListArray.from_arrays(flat, size) if pa.types.is_fixed_size_list(kind) else flat
    return out


@contextlib.contextmanager
def _quiet_fast_writes(fast: bool = True) -> Iterator[None]:
    """Within the block: no ``datasets`` progress bars, SVT-AV1's banner cut to errors
    (``SVT_LOG=1``, unless set) and libav's notes to warnings; with ``fast``, no per-frame image
    embedding and the per-episode statistics of ``prl.episode_stats.fast_episode_stats`` (the same numbers).

    lerobot 0.6's ``DatasetWriter._save_episode_data`` runs ``embed_images`` on every episode,
    a row-by-row ``datasets.map`` (~6 ms a frame) that changes nothing when no feature is an
    image (a video lives in its MP4, not in the table); with ``fast`` the writer's reference to it
    is replaced by the identity for the block (only when ``FEATURES`` holds no image). All is
    restored afterwards.
    """
    import datasets  # heavy (pyarrow, pandas): only around a write

    bars = datasets.is_progress_bar_enabled()
    datasets.disable_progress_bars()
    svt_log = os.environ.get("SVT_LOG")
    os.environ.setdefault("SVT_LOG", "1")  # read by SVT-AV1 when an encoder starts
    import av.logging  # heavy (libav): only around a write

    # lerobot hands libav's log back to libav's own printer after each encoding; its level (INFO by default,
    # not readable back) decides whether the MP4 muxer's "Starting second pass" notes reach stderr
    av.logging.set_libav_level(av.logging.WARNING)
    patched = None
    if fast and all(spec["dtype"] != "image" for spec in FEATURES.values()):
        from lerobot.datasets import dataset_writer  # heavy: only to patch it for the block

        if callable(getattr(dataset_writer, "embed_images", None)):
            patched = dataset_writer.embed_images
            dataset_writer.embed_images = lambda dataset: dataset
    stats = fast_episode_stats() if fast else contextlib.nullcontext()
    try:
        with stats:
            yield
    finally:
        if patched is not None:
            from lerobot.datasets import dataset_writer  # already loaded above: the same module

            dataset_writer.embed_images = patched
        if svt_log is None:
            os.environ.pop("SVT_LOG", None)
        av.logging.set_libav_level(av.logging.INFO)
        if bars:
            datasets.enable_progress_bars()
