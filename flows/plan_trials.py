"""Prefect task: execute a set of plans on randomised scenes of one task (cached on its inputs)."""

from __future__ import annotations

from prefect import task
from prefect.cache_policies import INPUTS, TASK_SOURCE

from envs.trials import TrialOutcome


@task(name="plan-trials", task_run_name="trials-{task_name}-{kind}", cache_policy=INPUTS + TASK_SOURCE,
      persist_result=True)
def plan_trials(task_name: str, kind: str, n: int, seed: int, n_frames: int,
                code_version: str) -> list[TrialOutcome]:
    """Run ``n`` plans of ``kind`` ('expert', 'prior', 'uniform') on scenes seeded from ``seed``.

    ``code_version`` is part of the cache key so a code change re-runs the simulation.
    """
    from envs.trials import plan_set, run_trials, trial_scene_seeds

    return run_trials(task_name, plan_set(task_name, kind, n, seed), trial_scene_seeds(seed, n), n_frames=n_frames)
