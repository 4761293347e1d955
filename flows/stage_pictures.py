"""Stage ``pictures-<task>``: a rendered picture of each executor stage of the task's expert plan."""

from __future__ import annotations

from pathlib import Path

from prefect import task
from prefect.cache_policies import NO_CACHE

from flows.check_assets import Assets
from prl import tracking


@task(name="pictures", task_run_name="pictures-{task_name}", cache_policy=NO_CACHE)
def pictures_stage(assets: Assets, task_name: str, seed: int, out_dir: Path) -> list[Path]:
    """Render PNGs of each stage of the expert plan on the scene of ``seed`` into ``out_dir`` and log them."""
    import mlflow  # heavy: mlflow

    from envs.render_stages import render_stages
    from envs.tasks import task_class

    with tracking.child_run(f"pictures-{task_name}", params={"plb_n_plans": assets.plb_n_plans}):
        paths = render_stages(task_name, tuple(task_class(task_name).expert_plan), seed, out_dir)
        for path in paths:
            mlflow.log_artifact(str(path), artifact_path=f"{task_name}_stages")
    return paths
