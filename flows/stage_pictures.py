"""Prefect task: render a picture of each executor stage of one plan."""

from __future__ import annotations

from pathlib import Path

from prefect import task
from prefect.cache_policies import NO_CACHE


@task(name="stage-pictures", task_run_name="pictures-{task_name}", cache_policy=NO_CACHE)
def stage_pictures(task_name: str, plan: tuple[int, ...], seed: int, out_dir: Path) -> list[Path]:
    """Render PNGs of each stage of ``plan`` on the scene of ``seed`` into ``out_dir``."""
    from envs.render_stages import render_stages

    return render_stages(task_name, plan, seed, out_dir)
