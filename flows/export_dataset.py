"""Stage ``export``: the demos, with their recovered labels, as a validated LeRobot v3.0 dataset (child run
``export``, the dataset logged as its MLflow input)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

from prefect import task
from prefect.cache_policies import NO_CACHE

from flows.recover_labels import Labels
from flows.synthesize import Synthesis
from prl import tracking
from prl.config import PipelineConfig
from prl.export_schema import DEFAULT_FPS, ExportReport, VideoSpec

#: Sources whose content decides the exported files (the export's cache key covers them).
EXPORT_SOURCES: tuple[str, ...] = (
    "prl/export.py", "prl/episode_stats.py", "prl/export_schema.py", "prl/demo.py", "prl/constants.py", "flows/export_dataset.py",
    "envs/video.py", "envs/scene_record.py", "envs/render_stages.py",
)


@dataclass(frozen=True)
class Dataset:
    """An exported LeRobot dataset: where it is, its repo id and content digest, and the export's report."""

    root: Path
    repo_id: str
    digest: str
    report: ExportReport


def export_dataset(demo_paths: list[Path], labels: dict[str, list[int]], root: Path, repo_id: str,
                   video: VideoSpec | None = None, workers: int = 1) -> ExportReport:
    """Write, reload, validate and move the dataset into place, with the cameras' video when ``video`` is given
    (each demo replayed by ``envs.video.DemoRenderer``); or, when the dataset at ``root`` was exported from the
    same demo bytes, labels and video settings by the same export code and lerobot version
    (``prl.export.export_key``), reload and validate it instead (``report.reused``). ``workers`` processes write
    a dataset without video (``prl.export.export_lerobot``; the same content, so not in the key). No result
    cache: the result is a directory that can change under it."""
    import lerobot  # heavy: lerobot

    from prl.export import export_key, export_lerobot, reusable_export
    from prl.version import source_version

    # the files that decide what an export writes; a change elsewhere (e.g. the RN) keeps the dataset
    version = f"{source_version(*EXPORT_SOURCES)}-lerobot{lerobot.__version__}"
    key = export_key(demo_paths, labels, repo_id, DEFAULT_FPS, version, video)
    report = reusable_export(root, repo_id, key, video)
    if report is not None:
        return report
    if video is None:
        return export_lerobot(demo_paths, root, repo_id=repo_id, per_episode_label=labels, key=key, workers=workers)
    from envs.video import DemoRenderer  # heavy: the simulator and its renderer, only to draw the video

    with DemoRenderer(video) as render:
        return export_lerobot(demo_paths, root, repo_id=repo_id, per_episode_label=labels, key=key, video=video,
                              render_images=render)


@task(name="export", cache_policy=NO_CACHE)
def export_stage(cfg: PipelineConfig, synthesis: Synthesis, labels: Labels) -> Dataset:
    """Export every task's demos into one dataset ``prl/<task>-<task>...`` under ``cfg.output_dir/datasets``."""
    import mlflow  # heavy: mlflow
    from mlflow.data.dataset_source_registry import resolve_dataset_source
    from mlflow.data.meta_dataset import MetaDataset

    from prl.dataset_files import dataset_digest

    tasks = list(synthesis.demo_paths)
    with tracking.child_run("export"):
        paths = [p for name in tasks for p in synthesis.demo_paths[name]]
        repo_id = f"prl/{'-'.join(tasks)}"
        root = cfg.output_dir / "datasets" / f"{'-'.join(tasks)}-seed{cfg.seed}"
        video = cfg.video_spec() if cfg.video else None
        report = export_dataset(paths, labels.recovered_by_path(synthesis), root, repo_id, video, cfg.workers)
        digest = dataset_digest(report.root)
        mlflow.log_metrics({"episodes": report.n_episodes, "frames": report.n_frames,
                            "size_mb": report.size_bytes / 1e6, "export_seconds": report.seconds,
                            "video_render_seconds": report.video_seconds, "reused": float(report.reused)})
        mlflow.log_params({"dataset_root": str(report.root), "repo_id": repo_id, "dataset_digest": digest,
                           "video": "none" if video is None else f"{video.width}x{video.height} at {video.fps} "
                           f"pictures/s, {report.video_codec}"})
        with warnings.catch_warnings():  # a local path matches two equivalent source kinds
            warnings.simplefilter("ignore", UserWarning)
            source = resolve_dataset_source(str(report.root))
        mlflow.log_input(MetaDataset(source, name=repo_id, digest=digest), context="demonstrations")
    print(f"LeRobot dataset {repo_id}: {report.n_episodes} episodes, {report.n_frames} frames"
          f"{'' if video is None else f', 2 camera videos ({report.video_codec})'} at {report.root} "
          f"({'an identical earlier export, ' if report.reused else ''}validated on reload)")
    return Dataset(report.root, repo_id, digest, report)
