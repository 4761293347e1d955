"""Prefect task: export demos (with their recovered labels) as a validated LeRobot v3.0 dataset."""

from __future__ import annotations

from pathlib import Path

from prefect import task
from prefect.cache_policies import NO_CACHE

from prl.export import DEFAULT_FPS, ExportReport

#: Sources whose content decides the exported files (the export's cache key covers them).
EXPORT_SOURCES: tuple[str, ...] = ("prl/export.py", "prl/demo.py", "prl/constants.py", "flows/export.py")


@task(name="export-lerobot", task_run_name="export-{repo_id}", cache_policy=NO_CACHE)
def export_dataset(demo_paths: list[Path], labels: dict[str, list[int]], root: Path, repo_id: str) -> ExportReport:
    """Write, reload, validate and move the dataset into place; or, when the dataset at ``root`` was
    exported from the same demo bytes and labels by the same export code and lerobot version
    (``prl.export.export_key``), reload and validate it instead (``report.reused``). Prefect's result
    cache is not used: the result is a directory that can change under it."""
    import lerobot

    from prl.export import export_key, export_lerobot, reusable_export
    from prl.version import source_version

    # the files that decide what an export writes; a change elsewhere (e.g. the RN) keeps the dataset
    version = f"{source_version(*EXPORT_SOURCES)}-lerobot{lerobot.__version__}"
    key = export_key(demo_paths, labels, repo_id, DEFAULT_FPS, version)
    report = reusable_export(root, repo_id, key)
    if report is not None:
        return report
    return export_lerobot(demo_paths, root, repo_id=repo_id, per_episode_label=labels, key=key)
