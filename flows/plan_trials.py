"""Stage ``trials-<task>``: the task's expert plan, plans sampled from the PLB prior and uniformly random plans,
each executed in simulation on domain-randomised scenes (child run ``trials-<task>``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from prefect import task
from prefect.cache_policies import INPUTS, NO_CACHE, TASK_SOURCE

from envs.trials import TrialOutcome
from flows.artifacts import publish_table, rate_row
from flows.check_assets import Assets
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
                code_version: str) -> list[TrialOutcome]:
    """Run ``n`` plans of ``kind`` ('expert', 'prior', 'uniform') on scenes seeded from ``seed``.

    ``code_version`` is part of the cache key so a code change re-runs the simulation.
    """
    from envs.trials import plan_set, run_trials, trial_scene_seeds  # heavy: loads the simulator

    return run_trials(task_name, plan_set(task_name, kind, n, seed), trial_scene_seeds(seed, n), n_frames=n_frames)


@task(name="trials", task_run_name="trials-{task_name}", cache_policy=NO_CACHE)
def trials_stage(cfg: PipelineConfig, assets: Assets, task_name: str, out_dir: Path, code_version: str) -> Trials:
    """Run every plan kind of ``envs.trials.PLAN_KINDS`` on ``cfg.eval_scenes`` scenes and log rates, measures,
    per-scene outcomes and a bar chart."""
    from envs.tasks import task_class  # heavy: loads the simulator
    from envs.trials import PLAN_KINDS, kind_seed

    with tracking.child_run(f"trials-{task_name}", params={"task": task_name, "scenes": cfg.eval_scenes,
                                                           "plb_n_plans": assets.plb_n_plans}):
        outcomes = {kind: plan_trials(task_name, kind, cfg.eval_scenes, kind_seed(cfg.seed, kind), cfg.episode_frames,
                                      code_version)
                    for kind in PLAN_KINDS}
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
