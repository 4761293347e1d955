"""Where a synthesis attempt's time goes: ``python -m experiments.attempt_profile [--tasks hammer,sweep] [--attempts 30]``.

An attempt as ``envs.synthesis.run_shard`` makes it (inside ``fast_resets()``): the scene seed and a plan drawn
from the task's prior with ``attempt_seeds(run_seed, task, shard, j)`` for j = 0..attempts-1, then
``env.reset(seed)``, the observation phase (``PlanExecutor.observe``) and the plan episode
(``PlanExecutor.run``). Timed per attempt in CPU time of the process (``time.process_time``: other processes on
the machine do not inflate it), with wrappers that only read the clock (the physics is unchanged):

* ``reset`` - ``env.reset(seed=...)`` (the scene rebuild);
* ``observe`` - the observation phase (its frames and x_manip sampling);
* per stage: ``<stage> physics`` - ``scene.step()``, the task's per-frame watch (``_after_simulation_step``)
  in its own row; ``planning`` - each stage's waypoint and its targets (IK); ``recording`` - the contact
  sensors and the other moving bodies read at the recorded frames; ``loop other`` - the rest of
  ``PlanExecutor.run`` (drive targets written, joint and pose reads of the recorded frames, ``Episode``'s
  set-up, the result);
* ``evaluate`` - the task's ``evaluate()`` at the end.

Printed per task: milliseconds per attempt and share of the attempt's time for each row, the physics frames per
attempt (observation + plan episode) and the attempts' yield; ``--end-decided`` profiles the attempts with
``ExecutorConfig.end_decided`` (the decisions' own time is then part of ``loop other``). Run it alone
(one simulation process).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # ``python experiments/attempt_profile.py``
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp/prl-runtime")
os.makedirs(os.environ["XDG_RUNTIME_DIR"], exist_ok=True)

import numpy as np

from envs.episode import Episode
from envs.execution import ExecutorConfig
from envs.executor import PlanExecutor
from envs.scene_record import SceneParts
from envs.sensors import ContactSensors
from envs.synthesis import attempt_seeds
from envs.tasks import fast_resets, make_env
from prl.constants import EPISODE_FRAMES
from prl.plb import load_plb
from prl.stages import STAGES


class _Clock:
    """Seconds accumulated per row name within one attempt, and the phase the stepping is in."""

    def __init__(self) -> None:
        self.rows: dict[str, float] = defaultdict(float)
        self.phase = "observe"
        self.frames = 0

    def add(self, name: str, seconds: float) -> None:
        self.rows[name] += seconds


def _timed(clock: _Clock, row: Callable[[], str], fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` with its wall time added to ``clock`` under the row ``row()`` names at call time."""
    now = time.process_time

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t = now()
        try:
            return fn(*args, **kwargs)
        finally:
            clock.add(row(), now() - t)

    return wrapper


def _instrument(env: Any, clock: _Clock) -> Callable[[], None]:
    """Wrap the env's and the episode's readers with clocks; returns the function that undoes the class wrappers."""
    now = time.process_time

    def step_physics() -> None:  # the body of PRLTaskEnv.step_physics, each half timed
        t0 = now()
        env.scene.step()  # looked up each time: every reset builds a new scene
        t1 = now()
        env._after_simulation_step()
        if clock.phase != "observe":  # the observation phase is timed as a whole
            clock.add(f"{clock.phase} physics", t1 - t0)
            clock.add("watch", now() - t1)
        clock.frames += 1

    on_stage_start = env.on_stage_start

    def stage_start(stage: str) -> None:
        clock.phase = stage
        on_stage_start(stage)

    env.step_physics = step_physics  # instance attributes: the episode binds env.step_physics once per run
    env.on_stage_start = stage_start
    env.evaluate = _timed(clock, lambda: "evaluate", env.evaluate)
    patched = [(Episode, "_stage_trajectory", "planning"), (ContactSensors, "read", "recording"),
               (SceneParts, "poses", "recording"), (SceneParts, "qpos", "recording")]
    originals = [(cls, name, getattr(cls, name)) for cls, name, _ in patched]
    for cls, name, row in patched:
        # the observation phase reads the contact sensors too: timed as a whole, not as recording
        setattr(cls, name, _timed(clock, (lambda row=row: row if clock.phase != "observe" else "(observe)"),
                                  getattr(cls, name)))

    def undo() -> None:
        for cls, name, fn in originals:
            setattr(cls, name, fn)

    return undo


def profile_task(task: str, attempts: int, run_seed: int = 0, shard: int = 0,
                 config: ExecutorConfig | None = None) -> dict[str, Any]:
    """Per-row mean seconds per attempt over ``attempts`` prior-sampled attempts of ``task``, and their frames."""
    plb = load_plb()
    env = make_env(task)
    executor = PlanExecutor(env, config or ExecutorConfig(n_frames=EPISODE_FRAMES))
    inner = env.unwrapped
    totals: dict[str, float] = defaultdict(float)
    frames, successes, wall = [], 0, 0.0
    try:
        executor.run(inner.expert_plan, seed=10**6)  # warm-up: imports, the IK chain
        clock = _Clock()
        undo = _instrument(inner, clock)
        try:
            with fast_resets():
                for j in range(attempts):
                    scene_seed, plan_seed = attempt_seeds(run_seed, task, shard, j)
                    plan = plb.sample_plan(task, np.random.default_rng(plan_seed))
                    clock.rows.clear()
                    clock.phase, clock.frames = "observe", 0
                    t0 = time.process_time()
                    env.reset(seed=int(scene_seed))
                    t1 = time.process_time()
                    executor.observe()
                    t2 = time.process_time()
                    result = executor.run(plan)
                    t3 = time.process_time()
                    rows = {k: v for k, v in clock.rows.items() if k != "(observe)"}
                    rows["loop other"] = max(0.0, (t3 - t2) - sum(rows.values()))
                    rows["reset"], rows["observe"] = t1 - t0, t2 - t1
                    for k, v in rows.items():
                        totals[k] += v
                    wall += t3 - t0
                    frames.append(clock.frames)
                    successes += bool(result.success)
        finally:
            undo()
    finally:
        env.close()
    n = max(1, attempts)
    return {"rows": {k: v / n for k, v in totals.items()}, "attempt_s": wall / n,
            "frames": float(np.mean(frames)) if frames else 0.0, "successes": successes, "attempts": attempts}


ROW_ORDER = ["reset", "observe", *[f"{s} physics" for s in STAGES], "watch", "planning", "recording",
             "loop other", "evaluate"]


def format_table(results: dict[str, dict[str, Any]]) -> str:
    """The profile of each task as one text table: ms per attempt (share of the attempt's time)."""
    tasks = list(results)
    lines = [f"{'row':<20}" + "".join(f"{t:>20}" for t in tasks)]
    for row in ROW_ORDER:
        if not any(row in r["rows"] for r in results.values()):
            continue
        cells = []
        for t in tasks:
            r = results[t]
            v = r["rows"].get(row)
            cells.append(f"{'-':>20}" if v is None else f"{v * 1e3:9.1f} ms ({v / r['attempt_s']:5.1%})")
        lines.append(f"{row:<20}" + "".join(cells))
    lines.append(f"{'attempt':<20}" + "".join(f"{results[t]['attempt_s'] * 1e3:9.1f} ms{'':>8}" for t in tasks))
    lines.append(f"{'physics frames':<20}" + "".join(f"{results[t]['frames']:>20.1f}" for t in tasks))
    lines.append(f"{'yield':<20}" + "".join(
        f"{results[t]['successes']:>13d} / {results[t]['attempts']:<4d}" for t in tasks))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default="hammer,sweep,unscrew,tweeze")
    parser.add_argument("--attempts", type=int, default=30)
    parser.add_argument("--run-seed", type=int, default=0)
    parser.add_argument("--shard", type=int, default=0)
    parser.add_argument("--end-decided", action="store_true", help="end decided failures early (ExecutorConfig)")
    args = parser.parse_args(argv)
    config = ExecutorConfig(n_frames=EPISODE_FRAMES, end_decided=args.end_decided)
    results = {}
    for task in (t.strip() for t in args.tasks.split(",")):
        results[task] = profile_task(task, args.attempts, args.run_seed, args.shard, config)
        print(f"{task}: {args.attempts} attempts, {results[task]['attempt_s'] * 1e3:.0f} ms each", flush=True)
    print(format_table(results))


if __name__ == "__main__":
    main()
