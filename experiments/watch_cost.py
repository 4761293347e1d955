"""What the tasks' per-frame watches cost: ``python -m experiments.watch_cost [--tasks hammer,sweep,tweeze] [--scenes 8]``.

A watch (``_after_simulation_step``: the hammer's nail credit, the sweep's cube watch, the tweeze's hand-on-cube
watch) runs after every physics frame of a plan episode. Per task, the expert plan runs on the same scenes with
the watch and with a no-op in its place, alternating which goes first; printed: the medians of the episode
loop's wall time (``EpisodeResult.wall_time_s``) and their ratio. Outcomes are not compared here (without the
watch a task's rule is not the same); the tasks' tests and trials check those.
"""

from __future__ import annotations

import argparse

import numpy as np

from envs.executor import PlanExecutor
from envs.tasks import fast_resets, make_env, task_class


def watch_ratio(task: str, scenes: int) -> tuple[float, float]:
    """(median loop seconds with the watch, without it) of the expert plan on ``scenes`` scenes."""
    cls = task_class(task)
    real = cls._after_simulation_step
    env = make_env(task)
    executor = PlanExecutor(env)
    times: dict[bool, list[float]] = {True: [], False: []}
    try:
        executor.run(cls.expert_plan, seed=0)  # warm-up: imports and the IK chain
        with fast_resets():
            for i in range(scenes):
                for watched in ((True, False) if i % 2 else (False, True)):
                    cls._after_simulation_step = real if watched else (lambda self: None)
                    times[watched].append(executor.run(cls.expert_plan, seed=1000 + i).wall_time_s)
    finally:
        cls._after_simulation_step = real
        env.close()
    return float(np.median(times[True])), float(np.median(times[False]))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default="hammer,sweep,tweeze")
    parser.add_argument("--scenes", type=int, default=8)
    args = parser.parse_args(argv)
    for task in args.tasks.split(","):
        with_watch, without = watch_ratio(task.strip(), args.scenes)
        print(f"{task}: expert episode loop {with_watch:.3f} s with the watch, {without:.3f} s without: "
              f"{with_watch / without:.2f}x (medians of {args.scenes})", flush=True)


if __name__ == "__main__":
    main()
