"""The PRL pipeline as a Prefect flow: ``python -m flows.full_pipeline [--profile paper] ...``.

Stages: assets (hand model + PLB) -> plan trials per task (the task's expert plan, plans sampled
from the PLB prior, uniformly random plans, each executed in simulation on domain-randomised
scenes) -> stage pictures of the expert plan -> scene synthesis (Dask) -> label recovery ->
LeRobot export -> PointNet -> RN training -> RN evaluation in simulation -> LN (A2C pre-trained on
the demonstrations, one run per task). Every run is one MLflow parent run with a child run per
stage; see the README for how to look at them.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from prefect import flow

from envs.trials import PLAN_KINDS, eval_scene_seeds, kind_seed
from flows.assets import verify_assets
from flows.evaluate_rn import log_rn_eval
from flows.export import export_dataset
from flows.labels import recover_labels
from flows.plan_trials import plan_trials
from flows.stage_pictures import stage_pictures
from flows.synthesize import shard_specs, synthesize
from flows.train_rn import evaluate_in_sim, rn_features, train_pointnet_stage
from prl import tracking
from prl.config import ConfigError, PipelineConfig, make_config
from prl.version import code_version, file_digest, git_commit


def synthesis_dir(cfg: PipelineConfig) -> Path:
    """Where a run's demos live; keyed on what fixes the attempts, so a re-run resumes there."""
    return cfg.output_dir / "synthesis" / f"seed{cfg.seed}-shards{cfg.n_shards}-frames{cfg.episode_frames}"


def _log_trials(task: str, outcomes_by_kind: dict[str, list], measure_key: str, out_dir: Path) -> dict[str, float]:
    import mlflow

    from envs.trials import success_rate
    from prl.plots import plot_trial_rates

    rates = {k: success_rate(v) for k, v in outcomes_by_kind.items()}
    for kind, outcomes in outcomes_by_kind.items():
        mlflow.log_metric(f"{task}/{kind}/success_rate", rates[kind])
        mlflow.log_metric(f"{task}/{kind}/mean_{measure_key}", float(np.mean([o.measure for o in outcomes])))
        mlflow.log_metric(f"{task}/{kind}/n", len(outcomes))
        mlflow.log_metric(f"{task}/{kind}/errors", sum(bool(o.error) for o in outcomes))
    rows = [{"kind": k, "seed": o.seed, "plan": list(o.plan), "success": o.success, "measure": o.measure,
             "fail": o.fail, "fault": o.fault, "error": o.error} for k, v in outcomes_by_kind.items() for o in v]
    mlflow.log_dict({"task": task, "measure": measure_key, "trials": rows}, f"{task}_trials.json")
    fig = plot_trial_rates(task, rates, {k: len(v) for k, v in outcomes_by_kind.items()},
                           {k: [o.measure for o in v] for k, v in outcomes_by_kind.items()}, measure_key,
                           out_dir / f"{task}_trial_rates.png")
    mlflow.log_artifact(str(fig))
    return rates


def _rn_stages(cfg: PipelineConfig, dataset_root: Path, repo_id: str, version: str,
               out_dir: Path) -> tuple[dict[str, dict[str, float]], dict[str, Any], Path]:
    """PointNet pre-training, RN training on the exported dataset, RN evaluation in simulation (child runs);
    returns the evaluation's success rates, the dataset's RN features and the PointNet checkpoint."""
    import mlflow

    from prl.features import FEATURE_LAYOUT, split_by_seed
    from prl.plb import load_plb
    from prl.plots import plot_rn_probabilities
    from prl.rn import RNConfig, per_dim_accuracy, plan_libraries, predict_proba, save_rn, train_rn

    plb = load_plb()
    models_dir = cfg.output_dir / "models"
    models_dir.mkdir(parents=True, exist_ok=True)
    with tracking.child_run("pointnet", params={"epochs": cfg.pn_epochs, "shapes": cfg.pn_shapes,
                                                "n_points": cfg.n_points}):
        pn_path, pn_history, reused = train_pointnet_stage(cfg.pn_epochs, cfg.pn_shapes, cfg.n_points, cfg.seed,
                                                           version, models_dir)
        mlflow.log_params({"checkpoint": str(pn_path), "reused": reused})
        for name, values in pn_history.items():
            for step, value in enumerate(values):
                mlflow.log_metric(f"pn/{name}", float(value), step=step)
        print(f"PointNet {'reused' if reused else 'trained'}: {pn_path.name}, "
              + ", ".join(f"{k} {v[-1]:.3f}" for k, v in pn_history.items()))

    rn_cfg = RNConfig(epochs=cfg.rn_epochs, seed=cfg.seed)
    with tracking.child_run("rn-train", params={**{f"rn.{k}": v for k, v in vars(rn_cfg).items()},
                                                "val_fraction": cfg.rn_val_fraction, "target": "commanded plan",
                                                "feature_layout": FEATURE_LAYOUT.to_json()}):
        data = rn_features(dataset_root, repo_id, pn_path, cfg.n_points)
        x, y = data["x"], data["plan"]
        train, val = split_by_seed(data["seeds"], cfg.rn_val_fraction, salt=cfg.seed)
        mlflow.log_metrics({"n_train": len(train), "n_val": len(val)})

        def log_epoch(epoch: int, metrics: dict[str, float]) -> None:
            mlflow.log_metrics({k: float(v) for k, v in metrics.items()}, step=epoch)

        model, _ = train_rn(x[train], y[train], rn_cfg, x[val], y[val], on_epoch=log_epoch)
        acc = per_dim_accuracy(model, x[val], y[val])
        mlflow.log_metrics({f"val_accuracy/{name}": float(a) for name, a in zip(plb.dim_names, acc)})
        print("RN validation accuracy: " + ", ".join(f"{n} {a:.2f}" for n, a in zip(plb.dim_names, acc)))
        tasks = np.array(data["tasks"])
        probs_by_task = {t: predict_proba(model, x[val][tasks[val] == t]) for t in cfg.tasks if np.any(tasks[val] == t)}
        fig = plot_rn_probabilities(probs_by_task, plb.dim_names, [d.choices for d in plb.dims],
                                    out_dir / "rn_probabilities.png")
        mlflow.log_artifact(str(fig))
        model.plan_libraries = plan_libraries(y[train], [data["tasks"][i] for i in train])  # rn-eval's decodings
        model.plan_priors = {t: plb.prior(t) for t in model.plan_libraries}  # the catalogue prior that synthesis samples from
        model.pointnet_sha256 = file_digest(pn_path)
        mlflow.log_metrics({f"{t}/plan_library_size": len(lib) for t, lib in model.plan_libraries.items()})
        rn_path = save_rn(model, rn_cfg, FEATURE_LAYOUT, models_dir / f"rn-seed{cfg.seed}.pt")
        mlflow.log_artifact(str(rn_path))
        diff = log_registered_rn(model, x[val])
        mlflow.log_metric("registered_reload_max_abs_diff", diff)

    results: dict[str, dict[str, float]] = {}
    with tracking.child_run("rn-eval", params={"scenes_per_split": cfg.rn_eval_scenes,
                                               "wide_randomization": cfg.wide_randomization}):
        for split, scale in (("train_ranges", 1.0), ("wide_ranges", cfg.wide_randomization)):
            for task in cfg.tasks:
                seeds = eval_scene_seeds(cfg.seed, cfg.rn_eval_scenes)
                out = evaluate_in_sim(rn_path, pn_path, task, seeds, cfg.n_points, cfg.episode_frames, scale,
                                      cfg.seed + 31)
                print(f"{task} ({split}): plans executed on {len(seeds)} unseen scenes")
                results[f"{task}/rn/{split}"] = log_rn_eval(task, split, out)
    return results, data, pn_path


def _ln_stage(cfg: PipelineConfig, data: dict[str, Any], pn_path: Path) -> dict[str, dict[str, float]]:
    """One LN run per task (``flows.ln``), each an MLflow child run, pre-trained on the dataset's demonstrations and
    evaluated on the RN evaluation's unseen scenes; the final policy is registered as ``prl-ln``."""
    from flows.ln import LNPoint, LNSetup, ln_point, write_demonstrations

    setup = LNSetup(timesteps=cfg.ln_timesteps, demo_dir=cfg.output_dir / "ln" / f"seed{cfg.seed}" / "demos",
                    pointnet_path=pn_path, out_dir=cfg.output_dir / "ln" / f"seed{cfg.seed}" / "points",
                    eval_seeds=tuple(eval_scene_seeds(cfg.seed, cfg.rn_eval_scenes)), n_points=cfg.n_points,
                    n_frames=cfg.episode_frames, n_envs=cfg.ln_envs, register=True)
    write_demonstrations(setup.demo_dir, list(cfg.tasks), data)
    results = {}
    for task in cfg.tasks:
        summary = ln_point(LNPoint(task, "physics", cfg.ln_demo_steps, cfg.seed), setup)
        ev = summary["eval"]
        rows = summary["rows"]
        print(f"{task} LN ({cfg.ln_timesteps} timesteps, pre-trained on {cfg.ln_demo_steps} demos): training success "
              f"{rows[-1]['success_rate'] if rows else float('nan'):.2f} in the last update; deterministic plan "
              f"{ev['successes']}/{ev['n']} on unseen scenes (95% CI {ev['ci95'][0]:.2f}-{ev['ci95'][1]:.2f})")
        results[f"{task}/ln"] = {"success_rate": ev["successes"] / max(ev["n"], 1)}
    return results


def log_registered_rn(model: Any, x_check: np.ndarray) -> float:
    """Log the RN as an MLflow model with a signature, register it as ``prl-rn``, reload it and return the
    largest absolute logit difference between the reloaded and the in-memory model on ``x_check``."""
    import mlflow
    import torch
    from mlflow.models import infer_signature

    model.eval()
    with torch.no_grad():
        logits = model(torch.as_tensor(x_check, dtype=torch.float32)).numpy()
    # pickle, not the traced 'pt2' default: a traced graph fixes the example's batch size
    info = mlflow.pytorch.log_model(model, name="rn", signature=infer_signature(x_check, logits),
                                    registered_model_name="prl-rn", serialization_format="pickle")
    reloaded = mlflow.pytorch.load_model(info.model_uri)
    reloaded.eval()
    with torch.no_grad():
        again = reloaded(torch.as_tensor(x_check, dtype=torch.float32)).numpy()
    return float(np.max(np.abs(again - logits)))


@flow(name="prl-full-pipeline", log_prints=True)
def full_pipeline(profile: str = "quick", overrides: dict[str, Any] | None = None) -> dict[str, dict[str, float]]:
    """Run every stage that exists, tracked in MLflow; return success rates per task and plan kind.

    ``overrides`` are ``PipelineConfig`` fields (e.g. ``{"tasks": ["hammer"], "demos_per_task": 8}``).
    """
    clean = dict(overrides or {})
    if "tasks" in clean and clean["tasks"] is not None:
        clean["tasks"] = tuple(clean["tasks"])
    if clean.get("output_dir"):
        clean["output_dir"] = Path(clean["output_dir"])
    return run_pipeline(make_config(profile, **clean))


def run_pipeline(cfg: PipelineConfig) -> dict[str, dict[str, float]]:
    """The flow body (called inside the Prefect flow)."""
    import mlflow

    if cfg.render:
        from envs.render_probe import require_rendering

        require_rendering("stage pictures (pass --no-render to skip them)")
    from mlflow.data.dataset_source_registry import resolve_dataset_source
    from mlflow.data.meta_dataset import MetaDataset

    import envs  # noqa: F401  (registers the hand agent and the tasks)
    from envs.synthesis import read_attempts, yield_report
    from envs.tasks import task_class
    from prl.export import dataset_digest
    from prl.label_recovery import agreement, format_agreement
    from prl.plb import load_plb

    uri = tracking.configure("prl")
    version = code_version()
    out_dir = cfg.output_dir / f"run-seed{cfg.seed}"
    out_dir.mkdir(parents=True, exist_ok=True)
    print(f"MLflow store: {uri}; outputs: {out_dir}")
    results: dict[str, dict[str, float]] = {}
    with tracking.parent_run(f"pipeline-{cfg.profile}", params=cfg,
                             tags={"code_version": version, "git_commit": git_commit()}) as parent:
        with tracking.child_run("assets"):
            summary = verify_assets()
            mlflow.log_params({k: str(v) for k, v in summary.items()})
        for task in cfg.tasks:
            cls = task_class(task)
            with tracking.child_run(f"trials-{task}", params={"task": task, "scenes": cfg.eval_scenes}):
                outcomes = {kind: plan_trials(task, kind, cfg.eval_scenes, kind_seed(cfg.seed, kind), cfg.episode_frames,
                                              version)
                            for kind in PLAN_KINDS}
                results[task] = _log_trials(task, outcomes, cls.measure_key, out_dir)
                print(f"{task}: success rate " + ", ".join(f"{k} {v:.2f}" for k, v in results[task].items()))
            if cfg.render:
                with tracking.child_run(f"pictures-{task}"):
                    paths = stage_pictures(task, tuple(cls.expert_plan), cfg.seed, out_dir / f"{task}_stages")
                    for path in paths:
                        mlflow.log_artifact(str(path), artifact_path=f"{task}_stages")
        with tracking.child_run("synthesis", params={"demos_per_task": cfg.demos_per_task, "n_shards": cfg.n_shards,
                                                      "workers": cfg.workers, "dask_address": cfg.dask_address}):
            demo_dir = synthesis_dir(cfg)
            specs = shard_specs(list(cfg.tasks), cfg.demos_per_task, cfg.seed, cfg.n_shards, demo_dir,
                                n_frames=cfg.episode_frames)
            already = sum(r["success"] for spec in specs for r in read_attempts(spec.dir))  # resumed runs
            t0 = time.perf_counter()
            shards = synthesize(specs, workers=cfg.workers, dask_address=cfg.dask_address)
            minutes = (time.perf_counter() - t0) / 60
            for task in cfg.tasks:
                report = yield_report(demo_dir, task)
                mlflow.log_metrics({f"{task}/{k}": v for k, v in report.items()})
                mlflow.log_dict(report, f"{task}_yield.json")
                print(f"{task}: {int(report['successes'])} demos kept of {int(report['attempts'])} attempts "
                      f"(yield {report['yield']:.2f}; {int(report['errors'])} raised, "
                      + ", ".join(f"{int(v)} {k.split('/')[1]}" for k, v in report.items() if k.startswith("faults/"))
                      + ")")
            new = sum(r.successes for r in shards) - already
            mlflow.log_metric("demos_per_minute", new / minutes if minutes > 0 else 0.0)
            mlflow.log_param("demo_dir", str(demo_dir))
        demo_paths = {task: sorted(p for r in shards if r.task == task for p in r.demo_paths) for task in cfg.tasks}
        plb = load_plb()
        labels: dict[str, dict[str, list[list[int]]]] = {}
        with tracking.child_run("labels"):
            for task in cfg.tasks:
                labels[task] = recover_labels(task, demo_paths[task], version)
                frac = agreement(np.array(labels[task]["commanded"]), np.array(labels[task]["recovered"]))
                mlflow.log_metrics({f"{task}/agreement/{name}": float(f) for name, f in zip(plb.dim_names, frac)})
                mlflow.log_dict(labels[task], f"{task}_labels.json")
                print(f"{task} label agreement:\n" + format_agreement(frac, len(demo_paths[task]), plb))
        with tracking.child_run("export"):
            paths = [p for task in cfg.tasks for p in demo_paths[task]]
            by_path = {str(p): lab for task in cfg.tasks
                       for p, lab in zip(demo_paths[task], labels[task]["recovered"])}
            repo_id = f"prl/{'-'.join(cfg.tasks)}"
            root = cfg.output_dir / "datasets" / f"{'-'.join(cfg.tasks)}-seed{cfg.seed}"
            report = export_dataset(paths, by_path, root, repo_id)
            digest = dataset_digest(report.root)
            mlflow.log_metrics({"episodes": report.n_episodes, "frames": report.n_frames,
                                "size_mb": report.size_bytes / 1e6, "export_seconds": report.seconds,
                                "reused": float(report.reused)})
            mlflow.log_params({"dataset_root": str(report.root), "repo_id": repo_id, "dataset_digest": digest})
            with warnings.catch_warnings():  # a local path matches two equivalent source kinds
                warnings.simplefilter("ignore", UserWarning)
                source = resolve_dataset_source(str(report.root))
            mlflow.log_input(MetaDataset(source, name=repo_id, digest=digest),
                             context="demonstrations")
            print(f"LeRobot dataset {repo_id}: {report.n_episodes} episodes, {report.n_frames} frames at "
                  f"{report.root} ({'an identical earlier export, ' if report.reused else ''}validated on reload)")
        if cfg.train_rn:
            rn_results, data, pn_path = _rn_stages(cfg, report.root, repo_id, version, out_dir)
            results.update(rn_results)
            if cfg.train_ln:
                results.update(_ln_stage(cfg, data, pn_path))
        print(f"MLflow parent run {parent.info.run_id}: "
              f"mlflow ui --backend-store-uri {tracking.resolve_tracking_uri()}")
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="quick", help="quick (default) or paper")
    parser.add_argument("--tasks", default=None, help="comma-separated tasks, e.g. hammer")
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--scenes", type=int, default=None, help="randomised scenes per plan kind")
    parser.add_argument("--frames", type=int, default=None, help="physics frames per plan episode")
    parser.add_argument("--demos-per-task", type=int, default=None, help="demos kept per task by synthesis")
    parser.add_argument("--shards", type=int, default=None, help="synthesis shards per task")
    parser.add_argument("--workers", type=int, default=None, help="Dask local-cluster worker processes")
    parser.add_argument("--dask-address", default=None, help="use this Dask scheduler instead of a local cluster")
    parser.add_argument("--no-render", action="store_true", help="skip stage pictures")
    parser.add_argument("--skip-rn", action="store_true", help="stop after the dataset export (no PointNet/RN)")
    parser.add_argument("--rn-epochs", type=int, default=None, help="RN training epochs (paper: 200)")
    parser.add_argument("--pn-epochs", type=int, default=None, help="PointNet pre-training epochs")
    parser.add_argument("--pn-shapes", type=int, default=None, help="synthetic shapes for PointNet pre-training")
    parser.add_argument("--rn-eval-scenes", type=int, default=None,
                        help="unseen scenes per RN evaluation split (the LN is evaluated on the same)")
    parser.add_argument("--skip-ln", action="store_true", help="stop after the RN evaluation (no LN)")
    parser.add_argument("--ln-timesteps", type=int, default=None, help="RL timesteps per LN run (paper: 3200)")
    parser.add_argument("--ln-demo-steps", type=int, default=None,
                        help="demonstrations the LN is pre-trained on (paper: 1280; 0: pure RL)")
    parser.add_argument("--ln-envs", type=int, default=None, help="plan environments stepped in parallel by the LN")
    parser.add_argument("--output-dir", default=None)
    args = parser.parse_args(argv)
    overrides = {
        "tasks": [t.strip() for t in args.tasks.split(",")] if args.tasks else None, "seed": args.seed,
        "eval_scenes": args.scenes, "episode_frames": args.frames, "demos_per_task": args.demos_per_task,
        "n_shards": args.shards, "workers": args.workers, "dask_address": args.dask_address,
        "render": False if args.no_render else None, "output_dir": args.output_dir,
        "train_rn": False if args.skip_rn else None, "rn_epochs": args.rn_epochs, "rn_eval_scenes": args.rn_eval_scenes,
        "pn_epochs": args.pn_epochs, "pn_shapes": args.pn_shapes, "train_ln": False if args.skip_ln else None,
        "ln_timesteps": args.ln_timesteps, "ln_demo_steps": args.ln_demo_steps, "ln_envs": args.ln_envs,
    }
    overrides = {k: v for k, v in overrides.items() if v is not None}
    try:  # validate before any work starts (and before Prefect spins up)
        make_config(args.profile, **{**overrides, "tasks": tuple(overrides.get("tasks", ())) or None,
                                     "output_dir": Path(args.output_dir) if args.output_dir else None})
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    full_pipeline(profile=args.profile, overrides=overrides)
    return 0


if __name__ == "__main__":
    sys.exit(main())
