"""Stage ``trials-<task>``: the task's expert plan, plans sampled from the PLB prior and uniformly random plans,
each executed in simulation on domain-randomised scenes (child run ``trials-<task>``)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from prefect import flow, task
from prefect.cache_policies import INPUTS, NO_CACHE, TASK_SOURCE
from prefect.task_runners import ProcessPoolTaskRunner, ThreadPoolTaskRunner

from envs.trials import PLAN_KINDS, TrialOutcome, kind_seed
from flows.artifacts import publish_table, rate_row
from flows.check_assets import Assets
from flows.worker_variables import worker_variables
from prl import tracking
from prl.config import PipelineConfig


@dataclass(frozen=True)
class Trials:
    """One task's success rate per plan kind ('expert', 'prior', 'uniform') and the scenes behind each."""

    task: str
    rates: dict[str, float]
    n: dict[str, int]


@task(name="plan-trials", task_run_name="trials-{task_name}-{kind}", cache_policy=INPUTS + TASK_SOURCE,
      persist_result=True)
def plan_trials(task_name: str, kind: str, n: int, seed: int, n_frames: int,
                code_version: str, progress: bool = True) -> list[TrialOutcome]:
    """Run ``n`` plans of ``kind`` ('expert', 'prior', 'uniform') on scenes seeded from ``seed``.

    ``code_version`` is part of the cache key so a code change re-runs the simulation.
    """
    import envs  # noqa: F401  (registers the hand and the tasks, in a worker process too)
    from envs.trials import plan_set, run_trials, trial_scene_seeds  # heavy: loads the simulator

    return run_trials(task_name, plan_set(task_name, kind, n, seed), trial_scene_seeds(seed, n), n_frames=n_frames,
                      progress=progress)


@flow(name="plan-trials", validate_parameters=False)
def _trials_flow(jobs: list[tuple[str, str]], n: int, seed: int, n_frames: int, code_version: str,
                 progress: bool) -> list[list[TrialOutcome]]:
    futures = [plan_trials.submit(name, kind, n, kind_seed(seed, kind), n_frames, code_version, progress)
               for name, kind in jobs]
    return [f.result() for f in futures]


def run_all_trials(cfg: PipelineConfig, code_version: str) -> dict[str, dict[str, list[TrialOutcome]]]:
    """Every task's trials of every plan kind (``envs.trials.PLAN_KINDS``) on ``cfg.eval_scenes`` scenes:
    ``{task: {kind: outcomes}}``. With ``cfg.workers`` > 1 the task-kind pairs run at once in that many processes of
    their own (Prefect's ``ProcessPoolTaskRunner``; each builds its environments), with no progress bars, which
    would overwrite each other; else one after another in this process, with them. The outcomes do not depend on
    the number of processes: each pair's scenes and plans come from the run's seed. The processes report to this
    process's Prefect API (``flows.worker_variables.worker_variables``): without it each started a temporary server of its own."""
    jobs = [(name, kind) for name in cfg.tasks for kind in PLAN_KINDS]
    parallel = cfg.workers > 1 and len(jobs) > 1
    runner = ProcessPoolTaskRunner(max_workers=min(cfg.workers, len(jobs))) if parallel else \
        ThreadPoolTaskRunner(max_workers=1)
    saved = os.environ.get("PREFECT_API_URL")
    if parallel:  # the spawned processes inherit this process's environment
        os.environ["PREFECT_API_URL"] = worker_variables()["PREFECT_API_URL"]
    try:
        outcomes = _trials_flow.with_options(task_runner=runner)(jobs, cfg.eval_scenes, cfg.seed, cfg.episode_frames,
                                                                 code_version, not parallel)
    finally:
        if saved is None:
            os.environ.pop("PREFECT_API_URL", None)
        else:
            os.environ["PREFECT_API_URL"] = saved
    out: dict[str, dict[str, list[TrialOutcome]]] = {name: {} for name in cfg.tasks}
    for (name, kind), result in zip(jobs, outcomes, strict=True):
        out[name][kind] = result
    return out


@task(name="trials", task_run_name="trials-{task_name}", cache_policy=NO_CACHE)
def trials_stage(cfg: PipelineConfig, assets: Assets, task_name: str, out_dir: Path,
                 outcomes: dict[str, list[TrialOutcome]]) -> Trials:
    """Log one task's trials (``run_all_trials``: every plan kind of ``envs.trials.PLAN_KINDS`` on ``cfg.eval_scenes``
    scenes): rates, measures, per-scene outcomes and a bar chart."""
    from envs.tasks import task_class  # heavy: loads the simulator

    with tracking.child_run(f"trials-{task_name}", params={"task": task_name, "scenes": cfg.eval_scenes,
                                                           "plb_n_plans": assets.plb_n_plans}):
        measure_key = task_class(task_name).measure_key
        rates = _log_trials(task_name, outcomes, measure_key, out_dir)
    publish_table(f"trial-rates-{task_name}", [
        rate_row(sum(bool(o.success) for o in v), len(v), **{"plan kind": kind},
                 **{f"mean {measure_key}": round(float(np.mean([o.measure for o in v])), 3) if v else None})
        for kind, v in outcomes.items()], f"{task_name}: plans executed on {cfg.eval_scenes} randomised scenes")
    print(f"{task_name}: success rate " + ", ".join(f"{k} {v:.2f}" for k, v in rates.items()))
    return Trials(task_name, rates, {k: len(v) for k, v in outcomes.items()})


def _log_trials(task: str, outcomes_by_kind: dict[str, list], measure_key: str, out_dir: Path) -> dict[str, float]:
    import mlflow  # heavy: mlflow

    from envs.trials import success_rate
    from prl.plots import plot_trial_rates

    rates = {k: success_rate(v) for k, v in outcomes_by_kind.items()}
    for kind, outcomes in outcomes_by_kind.items():
        mlflow.log_metric(f"{task}/{kind}/success_rate", rates[kind])
        mlflow.log_metric(f"{task}/{kind}/mean_{measure_key}", float(np.mean([o.measure for o in outcomes])))
        mlflow.log_metric(f"{task}/{kind}/n", len(outcomes))
        mlflow.log_metric(f"{task}/{kind}/errors", sum(bool(o.error) for o in outcomes))
    rows = [{"kind": k, "seed": o.seed, "plan": list(o.plan), "success": o.success, "measure": o.measure,
             "fail": o.fail, "fault": o.fault, "error": o.error} for k, v in outcomes_by_kind.items() for o in v]
    mlflow.log_dict({"task": task, "measure": measure_key, "trials": rows}, f"{task}_trials.json")
    fig = plot_trial_rates(task, rates, {k: len(v) for k, v in outcomes_by_kind.items()},
                           {k: [o.measure for o in v] for k, v in outcomes_by_kind.items()}, measure_key,
                           out_dir / f"{task}_trial_rates.png")
    mlflow.log_figure(fig, f"{task}_trial_rates.png")
    return rates
