"""Committed LN results: with ``results_dir`` set (``--results-dir docs/results/ln`` in the experiment), each point
of an LN sweep that finishes writes its summary there (``prl.ln_summary``: settings, code version, dataset digest,
curve, evaluation per scene, MLflow run id, compute), and a sweep on any machine takes a point whose committed
summary is still valid as done. A fresh checkout with a new MLflow store thus resumes from the committed files
alone; ``python -m flows.report`` regenerates ``docs/results.md`` from them.

What invalidates a committed summary (the point is re-run and its file replaced; the sweep prints why):

- its ``code_version`` changed: any of ``prl.version.outcome_files(task, method)``, i.e. the task's own module
  (its scene, physics and success rule), the task base and registry, the hand, the executor and the episode
  stepping, the evaluation's trials, the LN and the library modules it imports, ``assets/``, and the method's own
  files: the plan environment, x and the export's readers for a plan-space method, the joint-control environment
  for a joint-space one (each summary records the digest of each file, ``code_files``, so the report names what
  changed);
- a setting changed: the LN's and SB3's parameters, the evaluation's scene seed or count, the plan environment's
  frames or surface points, the PointNet (its file name: a key of its config and code version), the dataset's
  recipe (``dataset_recipe``: the synthesis run that made the task's demonstrations, by its directory key of run
  seed, shards, frames and proposal, and their number), or ``POINT_PROCEDURE`` (bumped by hand when
  ``flows.train_ln.run_point`` changes what a point computes);
- other timesteps are another file (``<point>-t<timesteps>.json``): a budget never replaces another.

What does not: the README, docs, tests, a flows module's orchestration or tracking, another task's module, a new
module nobody of the above imports, the synthesis and red-team modules, the MLflow store (it need not exist), and
the bytes of the demonstrations and the PointNet as a new machine regenerates them from the same recipe (PhysX on
the CPU differs across machines in a few outcomes: ``prl.ln_summary``); their digests are recorded in each
summary (``dataset_digest``, ``pointnet_sha256``) and counted by the report. A malformed summary file stops the
sweep with an error naming it (fix or delete it). ``--reevaluate`` is refused with a results directory: a policy trained under one
code version and judged under another is not a result of either.
"""

from __future__ import annotations

import dataclasses
import datetime
from pathlib import Path
from typing import Any

import numpy as np
from prefect import task
from prefect.cache_policies import NO_CACHE

from envs.replay import synthesis_runs
from flows.train_ln import LNPoint, LNSetup, point_config, run_point
from prl import tracking
from prl.constants import EPISODE_FRAMES
from prl.export_schema import read_scenes
from prl.ln_summary import (
    compact,
    demonstrations_digest,
    read_summary,
    reuse_decision,
    summary_file_name,
    thin_rows,
    write_summary,
)
from prl.version import file_digest, method_family, outcome_file_digests, outcome_version, version_of

POINT_PROCEDURE = 1
"""Version of what ``flows.train_ln.run_point`` computes for a point (pre-training, training, evaluation), a
setting of every committed summary: bump it when a change there changes a point's outcome (``flows/`` is not in
``prl.version.outcome_files``)."""


def point_cores(n_envs: int) -> int:
    """The processes one LN point keeps busy: the main process (A2C; the one environment when ``n_envs`` is 1)
    and one per environment subprocess when there are several. A summary's ``cores``, the report's core-hours."""
    return 1 if n_envs == 1 else n_envs + 1


def point_settings(point: LNPoint, setup: LNSetup, eval_seed: int,
                   recipe: dict[str, Any] | None = None) -> dict[str, Any]:
    """What decides ``point``'s outcome beside its code version: the LN's and SB3's parameters
    (``prl.config.LNConfig.params`` of the point's config), the evaluation's scene seed and count, the procedure;
    for the plan-space methods also the plan environment's physics frames and surface points, the PointNet's file name
    (keyed by its config and code version) and the ``recipe`` of the task's demonstrations (``dataset_recipe``);
    joint control uses none of these, and joint_bc only the recipe. An imitation point's are its policy's settings (``prl.imitation``), the
    evaluation's, the procedure and the recipe."""
    common = {"eval_seed": int(eval_seed), "eval_scenes": len(setup.eval_seeds), "procedure": POINT_PROCEDURE}
    if point.method == "imitation":  # no LN: the policy's settings, on the same demonstrations' episodes
        policy = dataclasses.replace(setup.imitation, seed=point.seed)
        return {**{f"imitation.{k}": v for k, v in dataclasses.asdict(policy).items()}, **common, "dataset": recipe}
    settings: dict[str, Any] = {**point_config(point, setup.ln).params(), **common}
    if point.method == "joint_bc":  # the joint-control env, pre-trained on the demonstrations' joint actions
        settings.update(dataset=recipe)
    elif point.method != "joint":
        settings.update(n_frames=int(setup.n_frames or EPISODE_FRAMES), n_points=int(setup.n_points),
                        pointnet=Path(setup.pointnet_path).name, dataset=recipe)
    return settings


def dataset_recipe(dataset_root: Path, task_name: str) -> dict[str, Any]:
    """How the dataset's ``task_name`` demonstrations were made, in terms a new machine reproduces: the synthesis
    run directories they came from (by name: ``seed<N>-shards<S>-frames<F>-<proposal>``, from each episode's demo
    path ``.../<run>/<task>/shard<k>/ep<j>.npz``) and their number."""
    scenes = [s for s in read_scenes(dataset_root) if s["task"] == task_name]
    return {"synthesis": synthesis_runs(scenes), "episodes": len(scenes)}


def task_dataset_digest(dataset_root: Path, demo_dir: Path, task_name: str) -> str:
    """``prl.ln_summary.demonstrations_digest`` of ``task_name``'s demonstrations: the scene seeds from the dataset's
    scene records, the plans, rewards and any further per-episode arrays (not x) from ``demos-<task>.npz``.
    ValueError naming both files when the demonstrations are not the dataset's (another count, or rewards that are
    not its episodes' measures): a stale ``demos`` directory of another dataset."""
    from envs.tasks import task_class  # heavy: loads the simulator (the task's measure key)
    scenes = [s for s in read_scenes(dataset_root) if s["task"] == task_name]
    path = Path(demo_dir) / f"demos-{task_name}.npz"
    with np.load(path) as f:
        arrays = {k: np.asarray(f[k]) for k in f.files if k != "x"}
    plan, reward = arrays.pop("plan"), arrays.pop("reward")
    key = task_class(task_name).measure_key
    measured = np.array([float((s.get("outcome") or {}).get(key, np.nan)) for s in scenes], np.float32)
    if len(scenes) != len(plan) or not np.array_equal(measured, np.asarray(reward, np.float32)):
        raise ValueError(f"the demonstrations in {str(path)!r} ({len(plan)}) are not the {len(scenes)} {task_name} "
                         f"episodes of the dataset {str(dataset_root)!r}: delete that file (the sweep writes it "
                         f"again) or give another --output-dir")
    return demonstrations_digest(task_name, [int(s["seed"]) for s in scenes], plan, reward, arrays)


def point_records(points: list[LNPoint], setup: LNSetup, dataset_root: Path, eval_seed: int) -> dict[str, Any]:
    """``{point name: record}``: what each point would be run with now (``prl.ln_summary.RECORD_KEYS``)."""
    files = {(p.task, p.method): outcome_file_digests(p.task, p.method) for p in points}
    plan_tasks = sorted({p.task for p in points if p.method != "joint"})
    digests = {t: task_dataset_digest(dataset_root, setup.demo_dir, t) for t in plan_tasks}
    recipes = {t: dataset_recipe(dataset_root, t) for t in plan_tasks}
    pointnet = file_digest(setup.pointnet_path) if plan_tasks else None
    joint = {p.name: p.method == "joint" for p in points}
    return {p.name: {"point": {"task": p.task, "method": p.method, "demo_steps": p.demo_steps, "seed": p.seed},
                     "timesteps": 0 if p.method == "imitation" else int(setup.ln.timesteps),
                     "settings": point_settings(p, setup, eval_seed, None if joint[p.name] else recipes[p.task]),
                     "code_version": version_of(files[p.task, p.method]),
                     "code_files": files[p.task, p.method],
                     "dataset_digest": None if joint[p.name] else digests[p.task],
                     "pointnet_sha256": None if method_family(p.method) == "joint" else pointnet}
            for p in points}


def committed_summaries(points: list[LNPoint], results_dir: Path,
                        records: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """The committed summaries in ``results_dir`` that the sweep reuses (``prl.ln_summary.reuse_decision`` against
    ``records``), by point name, and one line per summary it will not reuse, saying why.
    ``prl.ln_summary.SummaryError`` naming a malformed file."""
    kept, notes = {}, []
    for p in points:
        path = Path(results_dir) / summary_file_name(p.name, records[p.name]["timesteps"])
        existing = read_summary(path) if path.is_file() else None
        reuse, why = reuse_decision(existing, records[p.name])
        if reuse:
            kept[p.name] = existing
        elif existing is not None:
            notes.append(f"{p.name}: re-run, {path.name} does not hold today's point ({why})")
    return kept, notes


def committed_summary(summary: dict[str, Any], record: dict[str, Any], started: str, finished: str,
                      cores: int) -> dict[str, Any]:
    """The committed form of ``flows.train_ln.run_point``'s ``summary``: its ``record``, the rounded curve (and an
    imitation point's training loss) and evaluation, the run id and the compute; no checkpoint (a local file) and no
    pre-training losses."""
    ev = summary["eval"]
    return {**record, "name": summary["name"], "run_id": summary["run_id"], "rows": compact(thin_rows(summary["rows"])),
            "eval": {"successes": int(ev["successes"]), "n": int(ev["n"]), "ci95": compact(list(ev["ci95"])),
                     "outcomes": compact(ev["outcomes"])},
            **({"loss": compact(thin_rows(summary["loss"]))} if "loss" in summary else {}),
            "train_seconds": round(float(summary["train_seconds"]), 1),
            "eval_seconds": round(float(summary.get("eval_seconds", 0.0)), 1),
            "started": started, "finished": finished, "cores": int(cores)}


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


@task(name="ln-committed", task_run_name="{point.name}", cache_policy=NO_CACHE)
def ln_committed_point(point: LNPoint, setup: LNSetup, parent_run_id: str | None, record: dict[str, Any],
                       results_dir: Path) -> dict[str, Any]:
    """``flows.train_ln.run_point``, then its committed summary written to ``results_dir``; returns that summary.
    The code version is taken again as the point starts (the sweep's may be older); should it change while the
    point runs, the summary keeps the one it started with, which a later sweep will not reuse."""
    if parent_run_id is not None:
        tracking.configure("prl")
    started, files = _now(), outcome_file_digests(point.task, point.method)
    version = version_of(files)
    if version != record["code_version"]:
        print(f"{point.name}: the {point.task} code changed since the sweep started ({record['code_version']} -> "
              f"{version}); recording {version}")
        record = {**record, "code_version": version, "code_files": files}
    summary = run_point(point, setup, parent_run_id)
    if outcome_version(point.task, point.method) != version:
        print(f"{point.name}: the {point.task} code changed while the point ran; its summary records the version "
              f"it started with ({version}), so a later sweep runs it again")
    path = write_summary(results_dir, committed_summary(summary, record, started, _now(), point_cores(setup.ln.n_envs)))
    print(f"{point.name}: summary written to {path}")
    return read_summary(path)
