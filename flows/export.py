"""Prefect task: export demos (with their recovered labels) as a validated LeRobot v3.0 dataset."""

from __future__ import annotations

from pathlib import Path

from prefect import task
from prefect.cache_policies import NO_CACHE

from prl.export import ExportReport


@task(name="export-lerobot", task_run_name="export-{repo_id}", cache_policy=NO_CACHE)
def export_dataset(demo_paths: list[Path], labels: dict[str, list[int]], root: Path, repo_id: str) -> ExportReport:
    """Write, reload, validate and move the dataset into place (not cached: the result is a directory)."""
    from prl.export import export_lerobot

    return export_lerobot(demo_paths, root, repo_id=repo_id, per_episode_label=labels)
