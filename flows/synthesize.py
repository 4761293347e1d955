"""Prefect flow: scene synthesis fanned out over shards with Dask (prefect-dask).

A ``LocalCluster`` of ``workers`` processes by default; ``dask_address`` points at any running
Dask scheduler instead. Shards are the unit of work; their seeds derive from the run seed, so
the result does not depend on the number of workers.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

from prefect import flow, task
from prefect.cache_policies import NO_CACHE
from prefect_dask import DaskTaskRunner
from tqdm.auto import tqdm

from envs.synthesis import ShardResult, ShardSpec, split_successes
from flows.artifacts import publish_table
from flows.plan_trials import Trials
from prl import tracking
from prl.config import PipelineConfig
from prl.constants import EPISODE_FRAMES


@dataclass(frozen=True)
class Synthesis:
    """The demos a synthesis run kept: their directory, each task's demo files (sorted) and yield report."""

    demo_dir: Path
    demo_paths: dict[str, list[Path]]
    reports: dict[str, dict[str, float]]


@task(name="synthesize-shard", task_run_name="synthesize-{spec.task}-shard{spec.shard}", cache_policy=NO_CACHE)
def synthesize_shard(spec: ShardSpec) -> ShardResult:
    """Run or resume one shard. Not cached by Prefect: the shard's own files are its cache
    (a finished shard returns at once, a killed one resumes)."""
    import envs  # noqa: F401  (registers the hand and the tasks in the Dask worker)
    from envs.synthesis import run_shard

    return run_shard(spec)


def shard_specs(tasks: list[str], demos_per_task: int, seed: int, n_shards: int, out_dir: Path,
                n_frames: int = EPISODE_FRAMES, max_attempts: int = 10_000) -> list[ShardSpec]:
    """The shards of a synthesis run (empty shards are left out)."""
    return [ShardSpec(task=t, shard=k, n_success=n, run_seed=seed, out_dir=Path(out_dir), n_frames=n_frames,
                      max_attempts=max_attempts)
            for t in tasks for k, n in enumerate(split_successes(demos_per_task, n_shards)) if n > 0]


def make_task_runner(workers: int, dask_address: str | None) -> DaskTaskRunner:
    """A Dask task runner: the given scheduler, or a local cluster of ``workers`` single-thread processes.

    The local workers are pointed at this process's Prefect API (``worker_env``). Without that, a run
    on Prefect's temporary server (no ``PREFECT_API_URL``) had every worker start a server of its own,
    which took about half of each worker's CPU: 1.79 worker-seconds per attempt against 0.83 for the
    same shards run by bare processes, 0.84 with it (2 workers, 30 hammer demos, steady part, 2026-11-30).
    """
    if dask_address:
        return DaskTaskRunner(address=dask_address)
    # no pages of scheduler and worker start-up chatter: the workers read dask's logging level from the
    # environment when they import distributed, before the nanny's ``env`` reaches them, so it is set here
    logging.getLogger("distributed").setLevel(logging.WARNING)
    os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")
    return DaskTaskRunner(cluster_kwargs={"n_workers": workers, "threads_per_worker": 1, "processes": True,
                                          "dashboard_address": None, "env": worker_env(),
                                          "silence_logs": logging.WARNING})


def worker_env() -> dict[str, str]:
    """Environment for local Dask workers: the Prefect API URL this process uses, Dask's logs at warnings only.

    When ``PREFECT_API_URL`` is unset, Prefect's temporary server of this process is started (if it
    is not yet) and its URL is passed on, so workers report to it instead of starting their own.
    """
    from prefect.client.orchestration import get_client  # heavy: prefect
    from prefect.settings import PREFECT_API_URL

    url = PREFECT_API_URL.value()
    if not url:
        with get_client(sync_client=True) as client:
            url = str(client.api_url)
    return {"PREFECT_API_URL": str(url).rstrip("/"), "DASK_LOGGING__DISTRIBUTED": "warning"}


def _watch(specs: list[ShardSpec], futures: list, period_s: float = 1.0) -> None:
    """A progress bar with the live yield, read from the shards' attempt logs until all shards end."""
    from envs.synthesis import read_attempts  # heavy: loads the simulator

    target = sum(spec.n_success for spec in specs)
    with tqdm(total=target, desc="synthesis", unit="demo") as bar:
        while True:
            rows = [r for spec in specs for r in read_attempts(spec.dir)]
            ok = sum(r["success"] for r in rows)
            bar.n = min(ok, target)
            bar.set_postfix(attempts=len(rows), yield_=f"{ok / len(rows):.2f}" if rows else "-")
            bar.refresh()
            # the Dask futures, not ``f.state``: that is an API call per future per poll, and on two
            # cores the server's share of CPU came out of the workers'
            if all(f.wrapped_future.done() for f in futures):
                break
            time.sleep(period_s)


@flow(name="prl-synthesize")
def _synthesize(specs: list[ShardSpec]) -> list[ShardResult]:
    futures = [synthesize_shard.submit(spec) for spec in specs]
    _watch(specs, futures)
    return [f.result() for f in futures]


def synthesize(specs: list[ShardSpec], workers: int = 2, dask_address: str | None = None) -> list[ShardResult]:
    """Run ``specs`` as a Prefect (sub)flow on a Dask task runner; return the shard results in order."""
    return _synthesize.with_options(task_runner=make_task_runner(workers, dask_address))(specs)


def synthesis_dir(cfg: PipelineConfig) -> Path:
    """Where a run's demos live; keyed on what fixes the attempts, so a re-run resumes there."""
    return cfg.output_dir / "synthesis" / f"seed{cfg.seed}-shards{cfg.n_shards}-frames{cfg.episode_frames}"


@flow(name="synthesis", log_prints=True, validate_parameters=False)
def synthesis_stage(cfg: PipelineConfig, trials: list[Trials]) -> Synthesis:
    """Stage ``synthesis`` (a subflow; child run ``synthesis``): ``cfg.demos_per_task`` successful demos per
    task, attempted on Dask (``synthesize``) after the plan trials, resumed where an earlier run stopped;
    the yield per task and the demos per minute logged."""
    import mlflow  # heavy: mlflow

    from envs.synthesis import read_attempts, yield_report

    tasks = [t.task for t in trials]
    with tracking.child_run("synthesis", params={"demos_per_task": cfg.demos_per_task, "n_shards": cfg.n_shards,
                                                  "workers": cfg.workers, "dask_address": cfg.dask_address}):
        demo_dir = synthesis_dir(cfg)
        specs = shard_specs(tasks, cfg.demos_per_task, cfg.seed, cfg.n_shards, demo_dir, n_frames=cfg.episode_frames)
        already = sum(r["success"] for spec in specs for r in read_attempts(spec.dir))  # resumed runs
        t0 = time.perf_counter()
        shards = synthesize(specs, workers=cfg.workers, dask_address=cfg.dask_address)
        minutes = (time.perf_counter() - t0) / 60
        reports = {}
        for name in tasks:
            reports[name] = report = yield_report(demo_dir, name)
            mlflow.log_metrics({f"{name}/{k}": v for k, v in report.items()})
            mlflow.log_dict(report, f"{name}_yield.json")
            print(f"{name}: {int(report['successes'])} demos kept of {int(report['attempts'])} attempts "
                  f"(yield {report['yield']:.2f}; {int(report['errors'])} raised, "
                  + ", ".join(f"{int(v)} {k.split('/')[1]}" for k, v in report.items() if k.startswith("faults/"))
                  + ")")
        publish_table("synthesis-yield", [
            {"task": name, "attempts": int(r["attempts"]), "demos kept": int(r["successes"]),
             "yield": round(r["yield"], 3), "raised": int(r["errors"]),
             **{f"ended: {k.split('/')[1]}": int(v) for k, v in r.items() if k.startswith("faults/")}}
            for name, r in reports.items()], "Demonstrations kept per task (plans sampled from the PLB prior)")
        new = sum(r.successes for r in shards) - already
        mlflow.log_metric("demos_per_minute", new / minutes if minutes > 0 else 0.0)
        mlflow.log_param("demo_dir", str(demo_dir))
    demo_paths = {name: sorted(p for r in shards if r.task == name for p in r.demo_paths) for name in tasks}
    return Synthesis(demo_dir, demo_paths, reports)
