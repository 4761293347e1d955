"""Experiment: what two busy cores give two bare simulations, the ceiling of any orchestration's speed-up.

``bench.bench_synthesis`` takes 2 Dask workers' speed-up over 1 and splits it into the workers' busy share and their
seconds per attempt; the second part is what the cores themselves give plus what runs beside the workers (the
flow's process, Prefect's temporary server). This experiment measures the first alone: the same shard's attempts (one
task's shard 0 from the prior, the same seed, so the very same attempts and physics) run bare (``run_shard``: no
Prefect, no Dask) in fresh processes, once by itself and once as ``--processes`` copies at the same time. Each
process imports first and waits at a start line, so only the simulation is timed, side by side. The runs go
1, k, k, 1 (``--repeats 2``, the default) because a shared host's speed drifts; the means are compared.

The ceiling is ``k x (seconds per attempt alone) / (seconds per attempt with k at once)``: what ``k`` workers would
give over one if nothing but the attempts ran and no worker ever waited. ``--pin`` sets each process to its own core
(``os.sched_setaffinity``), to see whether the scheduler's moving them between cores costs anything.
``--beside-server`` keeps Prefect's temporary server (what ``python -m flows.full_pipeline`` starts when no
``PREFECT_API_URL`` is set) running, idle, through every run: what it alone costs the simulations beside it.

``--dask`` runs the shards as the pipeline's workers run them instead: on a local Dask cluster of ``--processes``
single-thread workers with the pipeline's settings (``flows.synthesize.local_cluster_kwargs``; no Prefect), one shard
per worker, the workers started and their imports done before the clock starts: what the Dask path costs beyond
the cores.

Measured (eight runs, 2026-12-06): ``docs/archive/speed.md``, "What the two cores allow without any orchestration".

``python -m experiments.cores [--task hammer] [--attempts 200] [--processes 2] [--repeats 1|2] [--pin]
[--beside-server] [--dask]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

from prl.config import ConfigError, check_task_names

_POLL_S = 0.01


def ceiling_speedup(alone_s_per_attempt: float, together_s_per_attempt: float, processes: int) -> float:
    """Speed-up of ``processes`` simultaneous runs over one: ``processes`` x (alone / together) seconds per attempt."""
    if alone_s_per_attempt <= 0 or together_s_per_attempt <= 0:
        raise ValueError(f"seconds per attempt must be > 0, got {alone_s_per_attempt!r} and "
                         f"{together_s_per_attempt!r}")
    if processes < 1:
        raise ValueError(f"processes must be >= 1, got {processes!r}")
    return processes * alone_s_per_attempt / together_s_per_attempt


def run_order(processes: int, repeats: int) -> list[int]:
    """How many processes each run has: 1, k (``repeats`` 1) or 1, k, k, 1 (``repeats`` 2)."""
    if repeats not in (1, 2):
        raise ValueError(f"repeats must be 1 or 2, got {repeats!r}")
    return [1, processes] if repeats == 1 else [1, processes, processes, 1]


def _shard_times(task: str, attempts: int, seed: int, out: Path) -> dict[str, float]:
    """Run shard 0's first ``attempts`` attempts into ``out`` in this process; its counts and times."""
    import envs  # noqa: F401  (registers the hand and the tasks)
    from envs.synthesis import ShardSpec, run_shard

    spec = ShardSpec(task=task, shard=0, n_success=attempts, run_seed=seed, out_dir=out / "syn",
                     max_attempts=attempts)
    cpu0 = time.process_time()
    result = run_shard(spec, keep_env=True)
    return {"attempts": result.attempts, "successes": result.successes, "seconds": result.seconds,
            "cpu_seconds": time.process_time() - cpu0}


def _import_envs() -> None:
    import envs  # noqa: F401  (a worker's imports, before the clock starts)


def _child(task: str, attempts: int, seed: int, out: Path, go: Path, core: int | None) -> None:
    """One process: import, say ready, wait for ``go``, run the shard's ``attempts`` attempts, write the times."""
    _import_envs()
    if core is not None:
        os.sched_setaffinity(0, {core})
    (out / "ready").touch()
    while not go.exists():
        time.sleep(_POLL_S)
    (out / "result.json").write_text(json.dumps(_shard_times(task, attempts, seed, out)))


def _run_dask(k: int, args: argparse.Namespace, root: Path) -> list[dict[str, float]]:
    """The shards on a fresh local cluster of ``k`` workers set up as the pipeline's, one shard per worker."""
    # heavy: distributed and the pipeline's Dask settings, only with --dask
    import dask
    from distributed import Client, LocalCluster

    from flows.synthesize import LOCAL_DASK_CONFIG, local_cluster_kwargs

    with dask.config.set(LOCAL_DASK_CONFIG), LocalCluster(**local_cluster_kwargs(k)) as cluster, \
            Client(cluster) as client:
        client.run(_import_envs)
        futures = [client.submit(_shard_times, args.task, args.attempts, args.seed, root / f"p{i}", workers=[w],
                                 pure=False) for i, w in enumerate(client.scheduler_info()["workers"])]
        return client.gather(futures)


@contextmanager
def _prefect_server() -> Iterator[str]:
    """Prefect's temporary server, started as the pipeline's flows start it, for as long as the block runs."""
    # heavy: Prefect's server and the pipeline's settings for it, only with --beside-server
    from prefect.server.api.server import SubprocessASGIServer

    import flows  # noqa: F401

    server = SubprocessASGIServer()
    server.start()
    try:
        yield server.address
    finally:
        server.stop()


def _run(k: int, args: argparse.Namespace, root: Path) -> list[dict[str, float]]:
    """Start ``k`` processes, let them import, start them at once, and return each one's times."""
    go = root / "go"
    outs = [root / f"p{i}" for i in range(k)]
    cores = sorted(os.sched_getaffinity(0))  # the cores this process may use, not 0..k-1
    procs = []
    for i, out in enumerate(outs):
        out.mkdir(parents=True)
        cmd = [sys.executable, "-m", "experiments.cores", "--child", str(out), "--go", str(go),
               "--task", args.task, "--attempts", str(args.attempts), "--seed", str(args.seed)]
        if args.pin:
            cmd += ["--core", str(cores[i % len(cores)])]
        procs.append(subprocess.Popen(cmd))
    while not all((out / "ready").exists() for out in outs):
        if any(p.poll() not in (None, 0) for p in procs):
            raise RuntimeError(f"a measured process failed before its start (exit codes {[p.poll() for p in procs]})")
        time.sleep(_POLL_S)
    go.touch()
    codes = [p.wait() for p in procs]
    if any(codes):
        raise RuntimeError(f"a measured process failed (exit codes {codes})")
    return [json.loads((out / "result.json").read_text()) for out in outs]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="hammer")
    parser.add_argument("--attempts", type=int, default=200, help="attempts of the shard, in every process")
    parser.add_argument("--processes", type=int, default=2, help="processes run at once (k)")
    parser.add_argument("--repeats", type=int, default=2, choices=(1, 2), help="1: runs 1, k; 2: runs 1, k, k, 1")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--pin", action="store_true", help="pin each process to its own core")
    parser.add_argument("--beside-server", action="store_true",
                        help="keep Prefect's temporary server running, idle, beside every run")
    parser.add_argument("--dask", action="store_true",
                        help="run the shards on a local Dask cluster set up as the pipeline's, one per worker")
    parser.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--go", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--core", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    try:
        check_task_names([args.task])
    except ConfigError as err:
        parser.error(str(err))
    if args.attempts <= 0:
        parser.error(f"--attempts must be > 0, got {args.attempts}")
    if args.processes < 2:
        parser.error(f"--processes must be >= 2, got {args.processes}")
    if args.pin and args.dask:
        parser.error("--pin pins bare processes; it does not go with --dask")
    if args.child is not None:
        _child(args.task, args.attempts, args.seed, args.child, args.go, args.core)
        return

    print(f"{args.task}: {args.attempts} attempts of shard 0 per process, runs of "
          f"{run_order(args.processes, args.repeats)} processes{', pinned' if args.pin else ''}"
          f"{', beside an idle Prefect server' if args.beside_server else ''}"
          f"{', as Dask workers' if args.dask else ''}", flush=True)
    wall: dict[int, list[float]] = {1: [], args.processes: []}
    cpu: dict[int, list[float]] = {1: [], args.processes: []}
    with ExitStack() as stack:
        tmp = stack.enter_context(tempfile.TemporaryDirectory(prefix="experiments_cores_"))
        if args.beside_server:
            print(f"Prefect's temporary server at {stack.enter_context(_prefect_server())}", flush=True)
        for n, k in enumerate(run_order(args.processes, args.repeats)):
            results = (_run_dask if args.dask else _run)(k, args, Path(tmp) / f"run{n}")
            if len({(r["attempts"], r["successes"]) for r in results}) != 1:
                raise RuntimeError(f"the processes of one run made different attempts: {results}")
            wall[k] += [r["seconds"] / r["attempts"] for r in results]
            cpu[k] += [r["cpu_seconds"] / r["attempts"] for r in results]
            print(f"{k} process(es): s/attempt {', '.join(f'{r['seconds'] / r['attempts']:.3f}' for r in results)} "
                  f"(cpu {', '.join(f'{r['cpu_seconds'] / r['attempts']:.3f}' for r in results)}), "
                  f"{results[0]['successes']}/{results[0]['attempts']} successes", flush=True)
    alone, together = (sum(wall[k]) / len(wall[k]) for k in (1, args.processes))
    cpu_alone, cpu_together = (sum(cpu[k]) / len(cpu[k]) for k in (1, args.processes))
    print(f"s/attempt alone {alone:.3f} (cpu {cpu_alone:.3f}), {args.processes} at once {together:.3f} "
          f"(cpu {cpu_together:.3f}): {100 * (together / alone - 1):+.1f}% per attempt")
    print(f"ceiling of {args.processes} workers over 1: {ceiling_speedup(alone, together, args.processes):.2f}x")


if __name__ == "__main__":
    main()
