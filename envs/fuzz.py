"""Fuzzing the executor: uniformly random plans on widely randomised scenes, counting every way they end.

A valid plan on any scene a task can build must end as an ``EpisodeResult`` (a success or a failure with
its reason), never as an exception, and its recordings must be finite. ``fuzz_task`` runs ``n_pairs``
(scene, plan) pairs, each drawn from ``seed``, and counts successes, failures by fault
(``prl.stages.FAULTS``), exceptions (with their text) and non-finite recordings. After an exception the
environment is rebuilt, so one bad pair does not spoil the next.

    python -m envs.fuzz --tasks hammer,sweep --pairs 500 --randomization 4 --out docs/fuzz.json
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from envs.executor import PlanExecutor
from envs.tasks import TASK_ENV_IDS, fast_resets, make_env
from envs.trials import error_text
from prl.plb import load_plb


@dataclass
class FuzzReport:
    """Counts of one task's fuzz run."""

    task: str
    randomization: float
    seed: int
    pairs: int = 0
    """(scene, plan) pairs run."""
    successes: int = 0
    faults: dict[str, int] = field(default_factory=dict)
    """Failed attempts per fault: ``none`` (physics alone failed the plan) or one of ``prl.stages.FAULTS``."""
    exceptions: list[str] = field(default_factory=list)
    """One line per pair that raised: seed, plan and the error."""
    nonfinite: list[str] = field(default_factory=list)
    """One line per pair whose recordings or x_manip held NaN/inf."""


def episode_is_finite(result: object) -> bool:
    """Whether every recorded array of an ``EpisodeResult`` (and its x_manip) is finite."""
    arrays = [getattr(result, name) for name in ("qpos", "qvel", "target", "force", "contact_pos", "contact_normal",
                                                 "palm_pose", "tool_pose", "object_pose", "x_manip")]
    return all(bool(np.all(np.isfinite(a))) for a in arrays)


def fuzz_task(task: str, n_pairs: int, randomization: float = 4.0, seed: int = 0, progress: bool = True) -> FuzzReport:
    """Run ``n_pairs`` uniformly random plans on scenes of ``task`` at ``randomization``; count the endings."""
    if n_pairs <= 0:
        raise ValueError(f"n_pairs must be > 0, got {n_pairs!r}")
    plb = load_plb()
    rng = np.random.default_rng(seed)
    pairs = [(int(rng.integers(2**31 - 1)), [int(rng.integers(0, s)) for s in plb.sizes]) for _ in range(n_pairs)]
    report = FuzzReport(task=task, randomization=float(randomization), seed=int(seed))
    faults: Counter[str] = Counter()
    env = executor = None
    try:
        with fast_resets():
            for scene_seed, plan in tqdm(pairs, desc=f"fuzz {task} x{randomization:g}", disable=not progress, unit="pair"):
                if env is None:
                    env = make_env(task, randomization=randomization)
                    executor = PlanExecutor(env)
                report.pairs += 1
                try:
                    result = executor.run(plan, seed=scene_seed)
                except Exception as exc:  # noqa: BLE001 - counting them is the point
                    report.exceptions.append(f"seed {scene_seed} plan {plan}: {error_text(exc)}")
                    env.close()
                    env = None
                    continue
                report.successes += int(result.success)
                if not result.success:
                    faults[result.fault or "none"] += 1
                if not episode_is_finite(result):
                    report.nonfinite.append(f"seed {scene_seed} plan {plan}")
    finally:
        if env is not None:
            env.close()
    report.faults = dict(sorted(faults.items()))
    return report


def main(argv: list[str] | None = None) -> None:

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default=",".join(TASK_ENV_IDS), help="comma-separated task names (default: all)")
    parser.add_argument("--pairs", type=int, default=100, help="(scene, plan) pairs per task")
    parser.add_argument("--randomization", type=float, default=4.0, help="scale of the randomisation ranges")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None, help="write the reports as JSON here")
    args = parser.parse_args(argv)
    reports = []
    for task in [t.strip() for t in args.tasks.split(",") if t.strip()]:
        report = fuzz_task(task, args.pairs, args.randomization, args.seed)
        reports.append(report)
        print(f"{task}: {report.pairs} pairs at randomization {report.randomization:g}: "
              f"{report.successes} successes, failures by fault {report.faults}, "
              f"exceptions {len(report.exceptions)}, non-finite recordings {len(report.nonfinite)}")
        for line in report.exceptions + report.nonfinite:
            print("  ", line)
    if args.out is not None:  # one file for all tasks: a task's new report replaces its old one
        kept = json.loads(args.out.read_text()) if args.out.exists() else []
        done = {r.task for r in reports}
        rows = [r for r in kept if r["task"] not in done] + [asdict(r) for r in reports]
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(sorted(rows, key=lambda r: r["task"]), indent=1) + "\n")


if __name__ == "__main__":
    main()
