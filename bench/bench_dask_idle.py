"""Benchmark (not a test): the CPU an idle local Dask cluster takes, with distributed's intervals and with ours.

Synthesis runs on a local cluster of single-thread worker processes whose scheduler and nannies live in the flow's
process (``flows.synthesize.make_task_runner``). On a 2-core machine every share of a core that the cluster's own
periodic callbacks take comes out of the two workers' simulation. Each measurement starts a fresh cluster of
``--workers`` workers with one configuration, lets it settle, and reads the CPU time that this process and each worker
process spend over ``--seconds`` of idling (``psutil``); the two configurations alternate over ``--rounds``:

- ``distributed``: distributed's own intervals, the sampling profiler off (as before 2026-12-05;
  ``bench.bench_synthesis.DISTRIBUTED_INTERVALS``);
- ``ours``: ``flows.synthesize.LOCAL_DASK_CONFIG``.

    python -m bench.bench_dask_idle [--workers 2] [--seconds 30] [--rounds 2]
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # ``python bench/bench_dask_idle.py``
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def idle_cpu(config: dict[str, Any], workers: int, seconds: float) -> tuple[float, float]:
    """(this process, all workers) CPU over ``seconds`` of an idle local cluster, in shares of one core."""
    import dask  # heavy: dask, distributed and psutil, only to measure
    import psutil
    from distributed import Client, LocalCluster

    with dask.config.set(config), \
            LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                         silence_logs=logging.WARNING, config=config) as cluster, Client(cluster):
        time.sleep(5.0)  # the workers' imports and first heartbeats
        me = psutil.Process()
        procs = [me, *me.children(recursive=True)]
        before = [sum(p.cpu_times()[:2]) for p in procs]
        time.sleep(seconds)
        used = [sum(p.cpu_times()[:2]) - b for p, b in zip(procs, before, strict=True)]
    return used[0] / seconds, sum(used[1:]) / seconds


def main(argv: list[str] | None = None) -> int:
    from bench.bench_synthesis import DISTRIBUTED_INTERVALS  # after the sys.path insert when run as a file
    from flows.synthesize import LOCAL_DASK_CONFIG  # heavy: prefect, prefect-dask and dask behind it

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=30.0, help="idle seconds measured per cluster")
    parser.add_argument("--rounds", type=int, default=2, help="each configuration is measured once a round")
    args = parser.parse_args(argv)
    if args.workers < 1 or not args.seconds > 0 or args.rounds < 1:
        parser.error(f"--workers and --rounds must be >= 1 and --seconds > 0, got {args.workers!r}, "
                     f"{args.rounds!r} and {args.seconds!r}")
    logging.getLogger("distributed").setLevel(logging.WARNING)
    configs = {"distributed": DISTRIBUTED_INTERVALS, "ours": LOCAL_DASK_CONFIG}
    sums = {name: [0.0, 0.0] for name in configs}
    print(f"| round | configuration | this process (% of a core) | {args.workers} workers (% of a core) | total |\n"
          "|---|---|---|---|---|")
    for r in range(args.rounds):
        for name in (("distributed", "ours") if r % 2 == 0 else ("ours", "distributed")):
            here, workers = idle_cpu(configs[name], args.workers, args.seconds)
            sums[name][0] += here
            sums[name][1] += workers
            print(f"| {r} | {name} | {100 * here:.2f} | {100 * workers:.2f} | {100 * (here + workers):.2f} |", flush=True)
    total = {name: sum(v) / args.rounds for name, v in sums.items()}
    ratio = (f"{total['distributed'] / total['ours']:.1f}x less" if total["ours"] > 0 else
             "ours too small to measure: run longer (--seconds)")
    print(f"\nmean over rounds: distributed's intervals {100 * total['distributed']:.2f}% of a core, ours "
          f"{100 * total['ours']:.2f}%: {ratio}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
