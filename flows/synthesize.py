"""Prefect flow: scene synthesis fanned out over shards with Dask (prefect-dask).

A ``LocalCluster`` of ``workers`` processes by default; ``dask_address`` points at any running
Dask scheduler instead. Shards are the unit of work; their seeds derive from the run seed, so
the result does not depend on the number of workers.
"""

from __future__ import annotations

import json
import logging
import os
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import dask
from distributed import Client, Future
from prefect import flow
from prefect.context import FlowRunContext
from prefect_dask import DaskTaskRunner
from tqdm.auto import tqdm

from envs.synthesis import ShardResult, ShardSpec, split_successes
from flows.artifacts import publish_table
from flows.plan_trials import Trials
from flows.worker_variables import worker_variables
from prl import tracking
from prl.config import PipelineConfig
from prl.constants import EPISODE_FRAMES
from prl.proposal import ProposalConfig


@dataclass(frozen=True)
class Synthesis:
    """The demos a synthesis run kept: their directory, each task's demo files (sorted) and yield report."""

    demo_dir: Path
    demo_paths: dict[str, list[Path]]
    reports: dict[str, dict[str, float]]


def synthesize_shard(spec: ShardSpec) -> ShardResult:
    """Run or resume one shard's round in a Dask worker (a plain Dask call: ``submit_shard`` says why not a
    Prefect task). The shard's own files are its cache (a finished shard returns at once, a killed one resumes). The
    worker keeps the task's environment open for its next round."""
    import envs  # noqa: F401  (registers the hand and the tasks in the Dask worker)
    from envs.synthesis import run_shard

    return run_shard(spec, keep_env=True)


def submit_shard(client: Client, spec: ShardSpec) -> Future:
    """``synthesize_shard(spec)`` on the flow's Dask cluster, as a plain Dask future (key
    ``synthesize-<task>-shard<k>-round<r>-<token>``). Not a Prefect task run: the paper profile makes about 600
    (rounds of 32) to 1,400 (rounds of 8) shard-rounds, and each task run cost this process about 60 ms of a core
    to submit (Prefect serialises its settings context with every submission) and Prefect's server about as much to
    record, taken from the two workers on a 2-core machine (2 workers took 4.6% longer with rounds of 32,
    ``bench/bench_synthesis.py --submit both``, and 20% longer with rounds of 8 in a probe, ``docs/archive/speed.md``), and
    printed a line per shard-round. The synthesis subflow's per-round record (the ``synthesis-rounds`` table) and
    progress bar say what those task runs said."""
    return client.submit(synthesize_shard, spec, pure=False,
                         key=f"synthesize-{spec.task}-shard{spec.shard}-round{spec.round}-{uuid.uuid4().hex[:8]}")


def shard_specs(tasks: list[str], demos_per_task: int, seed: int, n_shards: int, out_dir: Path,
                n_frames: int = EPISODE_FRAMES, max_attempts: int = 10_000, replay_check: bool = False
                ) -> list[ShardSpec]:
    """The shards of a synthesis run (empty shards are left out)."""
    return [ShardSpec(task=t, shard=k, n_success=n, run_seed=seed, out_dir=Path(out_dir), n_frames=n_frames,
                      max_attempts=max_attempts, replay_check=replay_check)
            for t in tasks for k, n in enumerate(split_successes(demos_per_task, n_shards)) if n > 0]


#: distributed's settings for a local cluster, here and in its workers: no sampling profiler (``make_task_runner``),
#: and the periodic callbacks of every server (scheduler, nannies, workers) slowed from 20 ms (event-loop health
#: tick), 500 ms (system monitor, which feeds a dashboard the local cluster does not have) and 100 ms (the memory
#: monitor's look at each worker's size): an idle 2-worker cluster took 10.7% of a core with distributed's intervals
#: and 2.2% with these, this process's share 4.1-5.7% against 1.2-1.3% (2026-12-05, by a probe since removed,
#: ``bench/bench_dask_idle.py`` in git history; under load ``python -m bench.bench_synthesis --dask-config both``).
LOCAL_DASK_CONFIG: dict[str, Any] = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "10s",
    "distributed.worker.memory.monitor-interval": "1s",
}


def make_task_runner(workers: int, dask_address: str | None) -> DaskTaskRunner:
    """A Dask task runner: the given scheduler, or a local cluster of ``workers`` single-thread processes.

    The local workers are pointed at this process's Prefect API (``worker_variables``). Without that, a run
    on Prefect's temporary server (no ``PREFECT_API_URL``) had every worker start a server of its own,
    which took about half of each worker's CPU: 1.79 worker-seconds per attempt against 0.83 for the
    same shards run by bare processes, 0.84 with it (2 workers, 30 hammer demos, steady part, 2026-11-30).

    The local workers run without distributed's sampling profiler (``distributed.worker.profile.enabled`` in the
    config each nanny hands its worker). It keeps a tree of the running task's stacks per second for the last
    1,000 seconds: Python objects made after ``fast_resets()`` froze
    the heap, which every scene rebuild's ``gc.collect()`` walks, more the older the worker (an LN point 32 min into training spent 46%
    of its training thread in that walk, by py-spy; a probe since removed, ``bench/bench_worker_profile.py`` in git
    history; ``tests/envs/test_synthesis.py`` checks the workers run no profiler). The local cluster's
    scheduler and nannies run in this process, and each started the same profiler on this process's event loop
    (``distributed.core.Server``): a thread sampling every thread's stack every 10 ms, about 4% of a core taken from
    the workers on two cores, for a profile no one can see (the cluster has no dashboard). So a local cluster
    switches it off for the rest of this process (``dask.config``, set here: the cluster starts lazily, at the
    flow's first submit). The same goes for distributed's other periodic callbacks (``LOCAL_DASK_CONFIG``).
    """
    if dask_address:
        return DaskTaskRunner(address=dask_address)
    dask.config.set(LOCAL_DASK_CONFIG)
    # no pages of scheduler and worker start-up chatter: the workers read dask's logging level from the
    # environment when they import distributed, before the nanny's ``env`` reaches them, so it is set here
    logging.getLogger("distributed").setLevel(logging.WARNING)
    os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")
    return DaskTaskRunner(cluster_kwargs={**local_cluster_kwargs(workers), "env": worker_variables()})


def local_cluster_kwargs(workers: int) -> dict[str, Any]:
    """A local cluster of ``workers`` single-thread processes, no dashboard, warnings only, ``LOCAL_DASK_CONFIG``
    (the pipeline's, less the workers' Prefect environment that ``make_task_runner`` adds)."""
    return {"n_workers": workers, "threads_per_worker": 1, "processes": True, "dashboard_address": None,
            "silence_logs": logging.WARNING, "config": LOCAL_DASK_CONFIG}


class _LogTally:
    """Attempts and successes in the shards' attempt logs, read incrementally (only the bytes appended since the
    last look): re-parsing every log each second cost the flow process 14% of a core by attempt 5,000 of the
    paper profile, taken from the two workers on a 2-core machine."""

    def __init__(self, specs: list[ShardSpec]) -> None:
        self.paths = [spec.dir / "attempts.jsonl" for spec in specs]
        self.offsets = [0] * len(self.paths)
        self.attempts = self.successes = 0

    def update(self) -> tuple[int, int]:
        for i, path in enumerate(self.paths):
            try:
                size = path.stat().st_size
            except FileNotFoundError:
                continue
            if size < self.offsets[i]:  # rewritten without a torn tail on resume: count every log again
                self.offsets = [0] * len(self.paths)
                self.attempts = self.successes = 0
                return self.update()
            if size == self.offsets[i]:
                continue
            with open(path, "rb") as fh:
                fh.seek(self.offsets[i])
                data = fh.read(size - self.offsets[i])
            complete = data[: data.rfind(b"\n") + 1]  # a line being written is counted at the next look
            self.offsets[i] += len(complete)
            for line in complete.splitlines():
                self.attempts += 1
                self.successes += bool(json.loads(line)["success"])
        return self.attempts, self.successes


def _show(tally: _LogTally, bar: tqdm) -> None:
    """Update ``bar`` with the live demos and yield, read from the shards' attempt logs."""
    attempts, ok = tally.update()
    bar.n = min(ok, int(bar.total))
    bar.set_postfix(attempts=attempts, yield_=f"{ok / attempts:.2f}" if attempts else "-")
    bar.refresh()


@flow(name="prl-synthesize")
def _synthesize(specs: list[ShardSpec], proposal: ProposalConfig, poll_s: float = 0.2,
                show_s: float = 2.0) -> tuple[list[ShardResult], list[dict[str, Any]]]:
    """Each task's rounds (``envs.synthesis.rounds_by_task``) as Dask futures on the flow's task runner
    (``submit_shard``): a round's end is seen within ``poll_s``, the progress bar redrawn every ``show_s``."""
    from envs.synthesis import rounds_by_task  # heavy: loads the simulator

    client = FlowRunContext.get().task_runner.client  # the task runner's cluster: local, or at --dask-address
    timing: list[dict[str, Any]] = []
    tally = _LogTally(specs)
    shown = [0.0]
    with tqdm(total=sum(s.n_success for s in specs), desc="synthesis", unit="demo") as bar:
        def start(todo: list[ShardSpec]) -> tuple[int, float, list]:
            return todo[0].round, time.perf_counter(), [submit_shard(client, spec) for spec in todo]

        def collect(handle: tuple[int, float, list]) -> list[ShardResult] | None:
            r, t0, futures = handle
            if not all(f.done() for f in futures):
                return None
            results = [f.result() for f in futures]
            timing.append({"task": results[0].task, "round": r, "wall_s": time.perf_counter() - t0,
                           "results": results})
            return results

        def idle() -> None:
            if time.perf_counter() - shown[0] >= show_s:
                _show(tally, bar)
                shown[0] = time.perf_counter()
            time.sleep(poll_s)

        shards = rounds_by_task(specs, proposal, start, collect, idle)
        _show(tally, bar)
    return shards, timing


def synthesize(specs: list[ShardSpec], workers: int = 2, dask_address: str | None = None,
               proposal: ProposalConfig | None = None) -> list[ShardResult]:
    """Run ``specs`` round by round (``envs.synthesis.rounds_by_task``) as a Prefect (sub)flow on a Dask task
    runner; return the shard results in order."""
    return synthesize_timed(specs, workers, dask_address, proposal or ProposalConfig(kind="prior"))[0]


def synthesize_timed(specs: list[ShardSpec], workers: int, dask_address: str | None,
                     proposal: ProposalConfig) -> tuple[list[ShardResult], list[dict[str, Any]]]:
    """``synthesize``, and each task's round as it ran: ``{"task", "round", "wall_s", "results"}`` (the shard-rounds'
    results, each with the seconds its call took on its worker)."""
    return _synthesize.with_options(task_runner=make_task_runner(workers, dask_address))(specs, proposal)


def round_rows(demo_dir: Path, tasks: list[str], timing: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The per-task, per-round record (``prl.proposal.round_table``) with each round's compute run now: the
    shard-rounds' worker minutes and attempts per worker minute (rounds resumed from an earlier run have none)."""
    from envs.synthesis import task_attempts  # heavy: loads the simulator
    from prl.plb import load_plb
    from prl.proposal import round_table

    sizes = load_plb().sizes
    out = []
    for name in tasks:
        rows = task_attempts(demo_dir, name)
        for entry in round_table(rows, sizes):
            run = [t for t in timing if t.get("round") == entry["round"]]
            worker_s = sum(res.seconds for t in run for res in t["results"] if res.task == name)
            mine = sum(1 for t in run for res in t["results"] if res.task == name)
            entry = {"task": name, **entry}
            if mine:
                entry["worker_minutes"] = worker_s / 60
                entry["attempts_per_worker_minute"] = entry["attempts"] / (worker_s / 60) if worker_s > 0 else 0.0
            out.append(entry)
    return out


def synthesis_dir(cfg: PipelineConfig) -> Path:
    """Where a run's demos live; keyed on what fixes the attempts (the proposal's settings too), so a re-run
    resumes there."""
    p = cfg.proposal_config()
    how = "prior" if p.kind == "prior" else \
        f"adaptive-r{p.round_attempts}-s{p.smoothing:g}-f{p.floor:g}" + (f"-d{p.defensive:g}" if p.defensive else "") \
        + (f"-x{p.replay:g}" if p.replay else "") + ("-w" if p.weighted else "")
    checked = "-replayed" if cfg.replay_check else ""
    return (cfg.output_dir / "synthesis"
            / f"seed{cfg.seed}-shards{cfg.n_shards}-frames{cfg.episode_frames}-{how}{checked}")


@flow(name="synthesis", log_prints=True, validate_parameters=False)
def synthesis_stage(cfg: PipelineConfig, trials: list[Trials]) -> Synthesis:
    """Stage ``synthesis`` (a subflow; child run ``synthesis``): ``cfg.demos_per_task`` successful demos per
    task, attempted on Dask (``synthesize``) after the plan trials, resumed where an earlier run stopped;
    the yield per task and the demos per minute logged."""
    import mlflow  # heavy: mlflow

    from envs.synthesis import read_attempts, yield_report

    tasks = [t.task for t in trials]
    proposal = cfg.proposal_config()
    with tracking.child_run("synthesis", params={"demos_per_task": cfg.demos_per_task, "n_shards": cfg.n_shards,
                                                  "workers": cfg.workers, "dask_address": cfg.dask_address,
                                                  "replay_check": cfg.replay_check,
                                                  **{f"proposal.{k}": v for k, v in vars(proposal).items()}}):
        demo_dir = synthesis_dir(cfg)
        specs = shard_specs(tasks, cfg.demos_per_task, cfg.seed, cfg.n_shards, demo_dir, n_frames=cfg.episode_frames,
                            replay_check=cfg.replay_check)
        already = sum(r["success"] for spec in specs for r in read_attempts(spec.dir))  # resumed runs
        t0 = time.perf_counter()
        shards, timing = synthesize_timed(specs, cfg.workers, cfg.dask_address, proposal)
        minutes = (time.perf_counter() - t0) / 60
        rounds = round_rows(demo_dir, tasks, timing)
        log_rounds(rounds, proposal)
        reports = {}
        for name in tasks:
            reports[name] = report = yield_report(demo_dir, name, cfg.episode_frames)
            mlflow.log_metrics({f"{name}/{k}": v for k, v in report.items()})
            mlflow.log_dict(report, f"{name}_yield.json")
            print(f"{name}: {int(report['successes'])} demos kept of {int(report['attempts'])} attempts "
                  f"(yield {report['yield']:.2f}; {report['frames_per_attempt']:.0f} physics frames per attempt, "
                  f"{int(report['decided'])} ended early as decided failures; {int(report['errors'])} raised, "
                  + (f"{int(report['not_replayed'])} succeeded but not by their 50 Hz replay, "
                     if cfg.replay_check else "")
                  + ", ".join(f"{int(v)} {k.split('/')[1]}" for k, v in report.items() if k.startswith("faults/"))
                  + ")")
        publish_table("synthesis-yield", [
            {"task": name, "attempts": int(r["attempts"]), "demos kept": int(r["successes"]),
             "yield": round(r["yield"], 3), "frames per attempt": round(r["frames_per_attempt"], 1),
             "ended early (decided)": int(r["decided"]), "raised": int(r["errors"]),
             **({"not replayed": int(r["not_replayed"])} if cfg.replay_check else {}),
             **{f"ended: {k.split('/')[1]}": int(v) for k, v in r.items() if k.startswith("faults/")}}
            for name, r in reports.items()], f"Demonstrations kept per task (plans drawn from the {proposal.kind} "
                                             f"proposal)")
        new = sum(r.successes for r in shards) - already
        mlflow.log_metric("demos_per_minute", new / minutes if minutes > 0 else 0.0)
        mlflow.log_param("demo_dir", str(demo_dir))
    demo_paths = {name: sorted(p for r in shards if r.task == name for p in r.demo_paths) for name in tasks}
    return Synthesis(demo_dir, demo_paths, reports)


def log_rounds(rounds: list[dict[str, Any]], proposal: ProposalConfig) -> None:
    """The per-task, per-round record (``round_rows``) as MLflow metrics (step = round), a JSON artifact and the
    keyed Prefect table ``synthesis-rounds``."""
    import mlflow  # heavy: mlflow

    for row in rounds:
        metrics = {k: float(v) for k, v in row.items() if isinstance(v, int | float) and k not in ("round",)}
        mlflow.log_metrics({f"{row['task']}/round/{k}": v for k, v in metrics.items()}, step=int(row["round"]))
    mlflow.log_dict({"proposal": vars(proposal), "rounds": rounds}, "synthesis_rounds.json")
    publish_table("synthesis-rounds", [
        {"task": r["task"], "round": r["round"], "attempts": r["attempts"], "successes": r["successes"],
         "yield (95% CI)": f"{r['yield']:.2f} ({r['yield_ci95'][0]:.2f}-{r['yield_ci95'][1]:.2f})",
         "demos kept": r["kept"], "distinct plans kept": r["distinct_plans"],
         "entropy a0..a5 (nats)": " ".join(f"{e:.2f}" for e in r["entropy"]), "effective sample size": round(r["ess"], 1),
         "attempts per worker-minute": round(r.get("attempts_per_worker_minute", float("nan")), 1),
         "worker-hours": round(r.get("worker_minutes", float("nan")) / 60, 3)} for r in rounds],
        f"Synthesis per task and round ({proposal.kind} proposal; {proposal.round_attempts} attempts per shard and "
        f"round)")
