"""Plan trials: execute plans on domain-randomised scenes and collect outcomes.

Used to measure which plans physics lets succeed: a task's expert plan, plans
sampled from the task's prior in the Physical Laws Bank, and uniformly random plans.
Every outcome is the task's ``evaluate()`` of the simulated state.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from prl.constants import EPISODE_FRAMES
from prl.plb import load_plb


@dataclass(frozen=True)
class TrialOutcome:
    """One executed plan on one randomised scene."""

    task: str
    """Task name."""
    seed: int
    """Scene seed (domain randomisation)."""
    plan: tuple[int, ...]
    """The commanded plan vector."""
    success: bool
    """The task's success criterion on the final simulated state (False on a blow-up)."""
    measure: float
    """The task's measured quantity (e.g. nail descent in cm)."""
    fail: bool
    """The task's failure flag (tool lost, NaN)."""


def plan_set(task: str, kind: str, n: int, seed: int) -> list[tuple[int, ...]]:
    """``n`` plans of a kind: 'expert' (the task's expert plan repeated), 'prior' (sampled from the
    task's PLB prior) or 'uniform' (uniform over the Representation Space), seeded by ``seed``."""
    from envs.tasks import task_class

    plb = load_plb()
    rng = np.random.default_rng(seed)
    if kind == "expert":
        return [tuple(task_class(task).expert_plan)] * n
    if kind == "prior":
        return [tuple(int(v) for v in plb.sample_plan(task, rng)) for _ in range(n)]
    if kind == "uniform":
        return [tuple(int(rng.integers(0, s)) for s in plb.sizes) for _ in range(n)]
    raise ValueError(f"unknown plan kind {kind!r}; known: 'expert', 'prior', 'uniform'")


Policy = Callable[[int, Any, np.ndarray], Sequence[int]]
"""Chooses the plan of trial ``i`` from the live scene: ``policy(i, env, x_manip) -> plan``, where ``env`` is
the unwrapped task env right after the observation phase (``PlanExecutor.observe``) and ``x_manip``
the (784,) features of that phase."""


def run_policy(task: str, policy: Policy, seeds: Sequence[int], n_frames: int = EPISODE_FRAMES, randomization: float = 1.0,
               progress: bool = True, desc: str | None = None) -> list[TrialOutcome]:
    """On the scene of each seed: observe, let ``policy`` choose a plan, execute it; one outcome each, in order.

    ``randomization`` scales the task's randomisation ranges (1: the training ranges).
    """
    from envs.executor import ExecutorConfig, PlanExecutor
    from envs.tasks import fast_resets, make_env

    env = make_env(task, randomization=randomization)
    try:
        with fast_resets():
            executor = PlanExecutor(env, ExecutorConfig(n_frames=n_frames))
            key = env.unwrapped.measure_key
            out: list[TrialOutcome] = []
            bar = tqdm(list(seeds), desc=desc or f"{task} trials", disable=not progress, unit="plan")
            for i, seed in enumerate(bar):
                x_manip = executor.observe(seed=int(seed))
                result = executor.run(policy(i, env.unwrapped, x_manip))
                out.append(TrialOutcome(task=task, seed=int(seed), plan=tuple(int(v) for v in result.plan),
                                        success=bool(result.success), measure=float(result.outcome[key]),
                                        fail=bool(result.outcome.get("fail", False))))
                bar.set_postfix(success_rate=f"{np.mean([o.success for o in out]):.2f}")
            return out
    finally:
        env.close()


def run_trials(task: str, plans: Sequence[Sequence[int]], seeds: Sequence[int], n_frames: int = EPISODE_FRAMES,
               progress: bool = True, randomization: float = 1.0) -> list[TrialOutcome]:
    """Execute ``plans[i]`` on the scene of ``seeds[i]``; return one outcome each, in order."""
    if len(plans) != len(seeds):
        raise ValueError(f"plans and seeds differ in length: {len(plans)} != {len(seeds)}")
    return run_policy(task, lambda i, env, x_manip: plans[i], seeds, n_frames=n_frames,
                      randomization=randomization, progress=progress)


def success_rate(outcomes: Sequence[TrialOutcome]) -> float:
    """Fraction of successful outcomes (0.0 for none)."""
    return float(np.mean([o.success for o in outcomes])) if outcomes else 0.0
