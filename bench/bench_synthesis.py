"""Benchmark: successful demonstrations per minute with 1 and 2 Dask workers, in one run.

Both runs synthesise the same shards (same run seed, so the very same attempts) through the
real path (Prefect subflow on a fresh Dask ``LocalCluster``, worker start-up included) into
fresh directories; the ratio of their rates is the parallel speed-up. The same shards are also
run bare, one after the other in this process (``run_shard``: no Prefect, no Dask), and each
Dask run's worker-seconds per attempt are printed as a multiple of the bare seconds per attempt:
the cost of the orchestration (1.0 = none; worker start-up and an unevenly ending last shard
count against it). Then the paper profile's wall time is extrapolated from the 2-worker rate.
Run it long enough (minutes per run) that the workers' start-up (about 10 s of imports, once per run)
and the last, unevenly ending shard do not dominate: ``--demos 120 --shards 12``.
With several ``--tasks`` (``hammer,sweep``) each task's rounds run on their own (``envs.synthesis.rounds_by_task``),
as in the pipeline's four-task runs: a task's next round fills the workers while another task's round ends.
The machine's speed drifts on a shared host (the same 809 hammer attempts took one worker 244 s, then 323 s and 350 s
two days later): ``--repeats 2`` runs 1, 2, 2, 1 workers and takes the ratio of the sums.
``--dask-config both`` sets the local cluster's periodic callbacks at ``flows.synthesize.LOCAL_DASK_CONFIG``'s intervals
and at distributed's own side by side; ``--submit both`` submits the shard-rounds as plain Dask futures (the pipeline's
``flows.synthesize.submit_shard``) and as Prefect task runs (its path until 2026-12-05) side by side. Either way the
first variant runs 1, 2 workers, the second 2, 1, and with ``--repeats 2`` then the reverse.
``python -m bench.bench_synthesis [--demos 8] [--shards 4] [--tasks hammer] [--repeats 1|2] [--no-bare] [--proposal prior|adaptive] [--round-attempts N] [--dask-config ours|distributed|both | --submit dask|prefect|both]``
"""

from __future__ import annotations

import argparse
import functools
import tempfile
import time
from pathlib import Path
from typing import Any

from prl.config import ConfigError, check_task_names
from prl.proposal import PROPOSALS, ProposalConfig

#: distributed's own intervals of the periodic callbacks that ``flows.synthesize.LOCAL_DASK_CONFIG`` slows.
DISTRIBUTED_INTERVALS: dict[str, Any] = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "20ms",
    "distributed.admin.system-monitor.interval": "500ms",
    "distributed.worker.memory.monitor-interval": "100ms",
}


SUBMITS = ("dask", "prefect")
"""How the shard-rounds reach the workers: plain Dask futures (``flows.synthesize.submit_shard``) or Prefect task runs."""


class _TaskRunFuture:
    """A Prefect task run's future as ``flows.synthesize._synthesize`` reads a Dask future: ``done()`` from the Dask
    future under it (no API call), ``result()`` the task's return value."""

    def __init__(self, future: Any) -> None:
        self.future = future

    def done(self) -> bool:
        return self.future.wrapped_future.done()

    def result(self) -> Any:
        return self.future.result()


@functools.cache
def _shard_task() -> Any:
    """``flows.synthesize.synthesize_shard`` as the Prefect task it was until 2026-12-05."""
    # heavy: prefect, and the simulator behind flows.synthesize
    from prefect import task
    from prefect.cache_policies import NO_CACHE

    import flows.synthesize as synth

    return task(synth.synthesize_shard, name="synthesize-shard", cache_policy=NO_CACHE,
                task_run_name="synthesize-{spec.task}-shard{spec.shard}-round{spec.round}")


def _submit_as_task(client: Any, spec: Any) -> _TaskRunFuture:
    """``flows.synthesize.synthesize_shard(spec)`` as a Prefect task run on the flow's task runner (the pipeline's
    path until 2026-12-05)."""
    return _TaskRunFuture(_shard_task().submit(spec))


def _run(workers: int, tasks: list[str], demos: int, shards: int, seed: int, out: Path,
         proposal: ProposalConfig, dask_config: str = "ours", submit: str = "dask") -> tuple[float, int, int, float]:
    """Wall seconds, demos, attempts, and the workers' busy seconds (the shard-rounds' calls added up), on a local
    cluster with ``LOCAL_DASK_CONFIG`` ('ours') or distributed's intervals ('distributed'), the shard-rounds submitted
    as plain Dask futures ('dask') or Prefect task runs ('prefect')."""
    import contextlib
    from unittest import mock

    import dask

    import flows.synthesize as synth  # heavy: loads the simulator

    config = synth.LOCAL_DASK_CONFIG if dask_config == "ours" else DISTRIBUTED_INTERVALS
    specs = synth.shard_specs(tasks, demos, seed, shards, out)
    t0 = time.perf_counter()
    # make_task_runner sets its config for the rest of the process: the context restores it after the run
    with dask.config.set(config), mock.patch.object(synth, "LOCAL_DASK_CONFIG", config), \
            (mock.patch.object(synth, "submit_shard", _submit_as_task) if submit == "prefect" else contextlib.nullcontext()):
        results, timing = synth.synthesize_timed(specs, workers, None, proposal)
    wall = time.perf_counter() - t0
    busy = sum(res.seconds for t in timing for res in t["results"])
    return wall, sum(r.successes for r in results), sum(r.attempts for r in results), busy


def _run_bare(tasks: list[str], demos: int, shards: int, seed: int, out: Path,
              proposal: ProposalConfig) -> tuple[float, int, int]:
    import envs  # noqa: F401  (registers the hand and the tasks)
    from envs.synthesis import run_shard, synthesize_rounds
    from flows.synthesize import shard_specs

    t0 = time.perf_counter()
    results = synthesize_rounds(shard_specs(tasks, demos, seed, shards, out), proposal,
                                lambda todo: [run_shard(spec, keep_env=True) for spec in todo])
    wall = time.perf_counter() - t0
    return wall, sum(r.successes for r in results), sum(r.attempts for r in results)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demos", type=int, default=8, help="successful demos per task and run")
    parser.add_argument("--tasks", default="hammer", help="comma-separated tasks synthesised together")
    parser.add_argument("--shards", type=int, default=4, help="more shards than workers evens out the load")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--no-bare", action="store_true", help="skip the bare in-process run")
    parser.add_argument("--proposal", default="adaptive", choices=PROPOSALS,
                        help="the pipeline's default, adaptive: rounds with a barrier between them")
    parser.add_argument("--round-attempts", type=int, default=ProposalConfig.round_attempts)
    parser.add_argument("--repeats", type=int, default=1,
                        help="run 1, 2, 2, 1 workers (2 repeats: a drift of the machine's speed cancels to first order)")
    parser.add_argument("--dask-config", default="ours", choices=("ours", "distributed", "both"),
                        help="the local cluster's periodic callbacks: flows.synthesize.LOCAL_DASK_CONFIG, distributed's "
                             "own intervals, or both side by side (ours 1, 2, distributed 2, 1 workers, then the reverse)")
    parser.add_argument("--submit", default="dask", choices=(*SUBMITS, "both"),
                        help="the shard-rounds as plain Dask futures (the pipeline's), Prefect task runs, or both side "
                             "by side (dask 1, 2, prefect 2, 1 workers, then the reverse)")
    args = parser.parse_args()
    if args.repeats not in (1, 2):
        parser.error(f"--repeats must be 1 or 2, got {args.repeats}")
    if args.dask_config == "both" and args.submit == "both":
        parser.error("compare one thing at a time: --dask-config both or --submit both, not both")
    proposal = ProposalConfig(kind=args.proposal, round_attempts=args.round_attempts)
    tasks = [t.strip() for t in args.tasks.split(",") if t.strip()]
    try:
        check_task_names(tasks)
    except ConfigError as err:
        parser.error(str(err))
    # each variant: (label, dask config, submit)
    if args.dask_config == "both":
        variants = [("ours", "ours", args.submit), ("distributed", "distributed", args.submit)]
    elif args.submit == "both":
        variants = [(submit, args.dask_config, submit) for submit in SUBMITS]
    else:
        variants = [(f"{args.dask_config}, {args.submit}", args.dask_config, args.submit)]
    labels = tuple(v[0] for v in variants)
    if len(variants) == 1:
        order = [(variants[0], w) for w in (1, 2, 2, 1)[: 2 * args.repeats]]
    else:
        order = [(variants[0], 1), (variants[0], 2), (variants[1], 2), (variants[1], 1)]
        order += order[::-1] if args.repeats == 2 else []
    runs: dict[tuple[str, int], list[tuple[float, int, int, float]]] = {(c, w): [] for c in labels for w in (1, 2)}
    with tempfile.TemporaryDirectory() as tmp:
        for i, ((label, config, submit), workers) in enumerate(order):
            runs[label, workers].append(_run(workers, tasks, args.demos, args.shards, args.seed,
                                             Path(tmp) / f"run{i}", proposal, config, submit))
        bare = None if args.no_bare else _run_bare(tasks, args.demos, args.shards, args.seed, Path(tmp) / "bare",
                                                   proposal)
    print(f"\n{'+'.join(tasks)} synthesis, {args.demos} demos per task in {args.shards} shards each, run seed {args.seed}, {args.proposal} "
          f"proposal ({args.round_attempts} attempts per shard and round)")
    walls = {}
    for label in labels:
        mine = {w: rs for (c, w), rs in runs.items() if c == label}
        rows = {w: tuple(sum(r[i] for r in rs) for i in range(4)) for w, rs in mine.items()}
        walls[label] = rows
        print(f"\nvariant: {label}")
        print(f"{'workers':>8} {'wall s':>8} {'demos':>6} {'attempts':>9} {'demos/min':>10} {'attempts/min':>13} "
              f"{'busy':>6} {'worker s/attempt':>17}"
              + ("  (sums of the runs; each run's wall s: " + ", ".join(
                  f"{w} worker(s) {' and '.join(f'{r[0]:.1f}' for r in rs)}" for w, rs in mine.items()) + ")"
                 if len(order) > 2 else ""))
        for workers, (wall, demos, attempts, busy) in rows.items():
            print(f"{workers:>8} {wall:>8.1f} {demos:>6} {attempts:>9} {60 * demos / wall:>10.2f} "
                  f"{60 * attempts / wall:>13.1f} {busy / (workers * wall):>6.1%} {busy / attempts:>17.3f}")
        if bare is not None:
            for workers, (wall, _, attempts, _) in rows.items():
                print(f"{workers} worker(s): {workers * wall / attempts / (bare[0] / bare[2]):.2f}x the bare seconds "
                      f"per attempt")
        same = len({r[2] for rs in mine.values() for r in rs}) == 1
        print(f"speed-up with 2 workers: {rows[1][0] / rows[2][0]:.2f}x (same attempts: {same})")
    print("busy: the workers' share of the wall time spent in shard-rounds (the rest: start-up, the end of each round,\n"
          "the flow between rounds); worker s/attempt: their seconds per attempt (up with 2 workers: the cores shared)")
    if bare is not None:
        print(f"{'bare':>8} {bare[0]:>8.1f} {bare[1]:>6} {bare[2]:>9} {60 * bare[1] / bare[0]:>10.2f} "
              f"{60 * bare[2] / bare[0]:>13.1f}")
    if len(labels) == 2:
        for workers in (1, 2):
            print(f"{workers} worker(s): {labels[1]} / {labels[0]}, wall time "
                  f"{walls[labels[1]][workers][0] / walls[labels[0]][workers][0]:.3f}x")
    rows = walls[labels[0]]
    per_min = 60 * rows[2][1] / rows[2][0]
    print(f"extrapolated 2,000 demos per task ({'+'.join(tasks)}) at this yield on 2 workers ({labels[0]}): "
          f"{2000 * len(tasks) / per_min / 60:.1f} h")


if __name__ == "__main__":
    main()
