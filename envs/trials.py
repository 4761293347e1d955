"""Plan trials: execute plans on domain-randomised scenes and collect outcomes.

Used to measure which plans physics lets succeed: a task's expert plan, plans
sampled from the task's prior in the Physical Laws Bank, and uniformly random plans.
Every outcome is the task's ``evaluate()`` of the simulated state.
"""

from __future__ import annotations

import argparse
import logging
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from envs.execution import ExecutorConfig
from envs.executor import PlanExecutor
from envs.tasks import TASK_ENV_IDS, fast_resets, make_env, task_class
from prl.constants import EPISODE_FRAMES
from prl.plb import PLBError, load_plb, parse_plan

_log = logging.getLogger(__name__)


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
    fault: str = ""
    """The executor's fault if it ended the plan itself (``prl.stages.FAULTS``), else ``""``."""
    error: str = ""
    """The exception text if the attempt raised (a bug, a PhysX error): then a failure, and the trials went on."""
    outcome: dict[str, Any] = field(default_factory=dict, compare=False)
    """The task's whole ``evaluate()`` at the end (plain values: the measure and how it came about, such as the
    hammer's ``hand_drive_cm``); empty when the attempt raised."""


PLAN_KINDS: tuple[str, ...] = ("expert", "prior", "uniform")
"""The plan kinds of the trials: the task's expert plan, plans sampled from its PLB prior, uniform plans."""


def kind_seed(run_seed: int, kind: str) -> int:
    """The seed of one plan kind's trials in a run (the pipeline's trials stage and ``python -m envs.trials``)."""
    return run_seed + 7919 * PLAN_KINDS.index(kind)


def trial_scene_seeds(seed: int, n: int) -> list[int]:
    """The ``n`` scene seeds of a trial set seeded by ``seed``."""
    return [seed * 100_003 + i for i in range(n)]


def eval_scene_seeds(seed: int, n: int) -> list[int]:
    """The ``n`` unseen scenes of a run seeded ``seed`` on which the RN and the LN are evaluated."""
    return [10_000_000 + 1_000 * seed + i for i in range(n)]


def plan_set(task: str, kind: str, n: int, seed: int) -> list[tuple[int, ...]]:
    """``n`` plans of a kind: 'expert' (the task's expert plan repeated), 'prior' (sampled from the
    task's PLB prior) or 'uniform' (uniform over the Representation Space), seeded by ``seed``."""
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

    ``randomization`` scales the task's randomisation ranges (1: the training ranges). An attempt that
    raises (a bug, a PhysX error) is a failed outcome with the error text in ``error``, logged as a
    warning; the environment is rebuilt and the trials go on.
    """
    key = task_class(task).measure_key
    env = executor = None
    out: list[TrialOutcome] = []
    try:
        with fast_resets():
            bar = tqdm(list(seeds), desc=desc or f"{task} trials", disable=not progress, unit="plan")
            for i, seed in enumerate(bar):
                if env is None:
                    env = make_env(task, randomization=randomization)
                    executor = PlanExecutor(env, ExecutorConfig(n_frames=n_frames))
                plan: Sequence[int] = ()
                try:
                    x_manip = executor.observe(seed=int(seed))
                    plan = policy(i, env.unwrapped, x_manip)
                    result = executor.run(plan)
                except Exception as exc:  # noqa: BLE001 - one attempt's error must not end the trials
                    out.append(failed_outcome(task, int(seed), plan, exc))
                    _log.warning("%s trial %d (seed %d) raised: %s", task, i, seed, out[-1].error)
                    env.close()
                    env = None
                    continue
                out.append(TrialOutcome(task=task, seed=int(seed), plan=tuple(int(v) for v in result.plan),
                                        success=bool(result.success), measure=float(result.outcome[key]),
                                        fail=bool(result.outcome.get("fail", False)), fault=result.fault,
                                        outcome=dict(result.outcome)))
                bar.set_postfix(success_rate=f"{np.mean([o.success for o in out]):.2f}")
            return out
    finally:
        if env is not None:
            env.close()


def error_text(exc: BaseException) -> str:
    """``Type: message (file:line)`` of an exception, for attempt logs."""
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" ({Path(frames[-1].filename).name}:{frames[-1].lineno})" if frames else ""
    return f"{type(exc).__name__}: {exc}{where}"


def failed_outcome(task: str, seed: int, plan: Sequence[int], exc: BaseException) -> TrialOutcome:
    """The outcome of an attempt that raised: a failure with measure 0 and the error text."""
    return TrialOutcome(task=task, seed=seed, plan=tuple(int(v) for v in plan), success=False, measure=0.0,
                        fail=True, error=error_text(exc))


def run_trials(task: str, plans: Sequence[Sequence[int]], seeds: Sequence[int], n_frames: int = EPISODE_FRAMES,
               progress: bool = True, randomization: float = 1.0) -> list[TrialOutcome]:
    """Execute ``plans[i]`` on the scene of ``seeds[i]``; return one outcome each, in order. An invalid plan is
    bad input: ``ValueError`` naming it before anything runs (only a valid plan's attempt is recorded as an error)."""
    if len(plans) != len(seeds):
        raise ValueError(f"plans and seeds differ in length: {len(plans)} != {len(seeds)}")
    plb = load_plb()
    for i, plan in enumerate(plans):
        try:
            plb.validate_plan(plan)
        except ValueError as exc:
            raise ValueError(f"plan {i} of the trials: {exc}") from exc
    return run_policy(task, lambda i, env, x_manip: plans[i], seeds, n_frames=n_frames,
                      randomization=randomization, progress=progress)


def success_rate(outcomes: Sequence[TrialOutcome]) -> float:
    """Fraction of successful outcomes (0.0 for none)."""
    return float(np.mean([o.success for o in outcomes])) if outcomes else 0.0


def main(argv: list[str] | None = None) -> None:
    """``python -m envs.trials --task sweep --scenes 50``: success rates of a task's plans, without MLflow.

    By default the pipeline's trials (the same scenes as its trials stage): the task's expert plan, plans
    sampled from its prior and uniform plans; ``--plan`` runs one given plan on the trial scenes instead.
    Each line reports the task's own measure (``measure_key``)."""
    parser = argparse.ArgumentParser(description="Success rates of a task's plans on the pipeline's trial scenes "
                                                 "(expert, prior-sampled and uniform plans, or one --plan).")
    parser.add_argument("--task", required=True, choices=sorted(TASK_ENV_IDS))
    parser.add_argument("--scenes", type=int, default=50, help="randomised scenes per plan kind")
    parser.add_argument("--seed", type=int, default=0, help="the run seed (as the pipeline's --seed)")
    parser.add_argument("--kinds", default=",".join(PLAN_KINDS), help=f"plan kinds, any of {','.join(PLAN_KINDS)}")
    parser.add_argument("--plan", default=None, help="run this plan (e.g. 0,3,2,0,0,1) instead of the plan kinds")
    parser.add_argument("--randomization", type=float, default=1.0, help="scale of the randomisation ranges")
    args = parser.parse_args(argv)
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    unknown = [k for k in kinds if k not in PLAN_KINDS]
    if unknown or not kinds:
        parser.error(f"--kinds: unknown plan kind(s) {unknown or kinds}; known: {', '.join(PLAN_KINDS)}")
    if args.scenes < 1:
        parser.error(f"--scenes must be >= 1, got {args.scenes}")
    try:
        plan = parse_plan(args.plan) if args.plan is not None else None
    except PLBError as exc:
        parser.error(f"--plan: {exc}")
    key = task_class(args.task).measure_key
    runs = [("plan " + ",".join(map(str, plan.tolist())), args.seed)] if plan is not None else \
        [(kind, kind_seed(args.seed, kind)) for kind in kinds]
    for label, seed in runs:
        plans = [tuple(plan.tolist())] * args.scenes if plan is not None else plan_set(args.task, label, args.scenes, seed)
        outs = run_trials(args.task, plans, trial_scene_seeds(seed, args.scenes), randomization=args.randomization,
                          progress=False)
        k = sum(o.success for o in outs)
        print(f"{args.task} {label:<8} {k}/{len(outs)} = {k / len(outs):.2f}; mean {key} "
              f"{np.mean([o.measure for o in outs]):.2f}; errors {sum(bool(o.error) for o in outs)}", flush=True)


if __name__ == "__main__":
    main()
