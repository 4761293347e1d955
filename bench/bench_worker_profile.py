"""Benchmark (not a test): plan episodes in a Dask worker with distributed's sampling profiler on and off, in one run.

A Dask worker samples the stacks of the task it runs every 10 ms and keeps one tree of them per second for the
last 1,000 seconds (``distributed.worker.profile``, ``distributed.admin.low-level-log-length``). Those trees are
Python dicts created after a ``fast_resets()`` freeze, so every scene rebuild's ``gc.collect()`` (ManiSkill's
``_clear``) walks them, and the walk grows with the worker's age. Each measurement starts a fresh one-worker
local cluster with the profiler on or off (``make_task_runner`` turns it off) and runs, in that worker, the
hammer's plan environment (``envs.plan_env.PlanEnv``: reset + observation + x + one plan episode, the LN's
timestep) on the expert plan for ``--seconds``, inside ``fast_resets()`` after a warm-up, as an LN point does.
Per mode it prints the mean seconds per episode and per ``gc.collect`` over the first and the last third,
and the objects the collector tracks at the end; the two modes alternate over ``--rounds``.

    python -m bench.bench_worker_profile --pointnet outputs/models/pointnet-*.pt [--seconds 180] [--rounds 1]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

if __package__ in (None, ""):  # ``python -m`` not used
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np


def episodes_in_worker(pointnet: str, seconds: float, seed: int) -> dict:
    """Run hammer expert-plan episodes of ``PlanEnv`` for ``seconds``; per episode its wall time and the time spent
    in the garbage collector's full collections, and the number of objects it tracks at the end."""
    import gc

    from envs.plan_env import PlanEnv  # heavy: the simulator
    from envs.tasks import fast_resets, task_class

    env = PlanEnv("hammer", pointnet_path=pointnet, run_seed=seed)
    env.warm_up()
    plan = np.asarray(task_class("hammer").expert_plan)
    gc_seconds = [0.0]
    started = [0.0]

    def on_gc(phase: str, info: dict) -> None:
        if info["generation"] != 2:
            return
        if phase == "start":
            started[0] = time.perf_counter()
        else:
            gc_seconds[0] += time.perf_counter() - started[0]

    rows = []
    gc.callbacks.append(on_gc)
    try:
        with fast_resets():
            t_end = time.perf_counter() + seconds
            while time.perf_counter() < t_end:
                t0, g0 = time.perf_counter(), gc_seconds[0]
                env.reset()
                env.step(plan)
                rows.append((time.perf_counter() - t0, gc_seconds[0] - g0))
            tracked = len(gc.get_objects())
    finally:
        gc.callbacks.remove(on_gc)
        env.close()
    return {"rows": rows, "tracked": tracked}


def measure(profiler: bool, pointnet: Path, seconds: float, seed: int) -> dict:
    """``episodes_in_worker`` in a fresh one-worker local cluster with the worker profiler ``profiler``."""
    import dask  # heavy: dask and distributed, only to measure
    from distributed import Client, LocalCluster

    with dask.config.set({"distributed.worker.profile.enabled": profiler}), \
            LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
                         silence_logs=40) as cluster, Client(cluster) as client:
        return client.submit(episodes_in_worker, str(pointnet), seconds, seed, pure=False).result()


def thirds(rows: list[tuple[float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """Mean (episode s, gc s) over the first and over the last third of ``rows``."""
    a = np.asarray(rows)
    k = max(1, len(a) // 3)
    return a[:k].mean(axis=0), a[-k:].mean(axis=0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pointnet", required=True, type=Path, help="a PointNet checkpoint (models/pointnet-*.pt)")
    parser.add_argument("--seconds", type=float, default=180.0, help="episodes run per measurement, in seconds")
    parser.add_argument("--rounds", type=int, default=1)
    args = parser.parse_args(argv)
    if not args.pointnet.is_file():
        parser.error(f"no PointNet checkpoint at {str(args.pointnet)!r}")
    if not args.seconds > 0 or args.rounds < 1:
        parser.error(f"--seconds must be > 0 and --rounds >= 1, got {args.seconds!r} and {args.rounds!r}")
    last: dict[bool, list[float]] = {True: [], False: []}
    print("| profiler | episodes | s/episode, first third | last third | gc s/episode, first third | last third "
          "| objects tracked at the end |\n|---|---|---|---|---|---|---|")
    for r in range(args.rounds):
        for on in ((True, False) if r % 2 == 0 else (False, True)):
            out = measure(on, args.pointnet, args.seconds, seed=r)
            (e0, g0), (e1, g1) = thirds(out["rows"])
            last[on].append(e1)
            print(f"| {'on' if on else 'off'} | {len(out['rows'])} | {e0:.3f} | {e1:.3f} | {g0:.3f} | {g1:.3f} "
                  f"| {out['tracked']:,} |", flush=True)
    on, off = float(np.median(last[True])), float(np.median(last[False]))
    print(f"\nlast third, median over rounds: profiler on {on:.3f} s/episode, off {off:.3f}: off is {on / off:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
