"""The PRL pipeline as a Prefect flow: ``python -m flows.full_pipeline [--profile paper] ...``.

The DAG, one module per stage under ``flows/``, each a Prefect task or subflow taking the previous stages'
results and logging its own MLflow child run under the run's parent run::

    assets -> trials-<task> -> synthesis -> labels -> export -> features -> rn-train -> rn-eval -> ln
    assets -> pictures-<task>      assets -> pointnet -> features      synthesis -> export      features -> ln

assets (hand model + PLB) -> plan trials per task (expert, prior-sampled and uniformly random plans
executed on domain-randomised scenes) and stage pictures of the expert plan -> scene synthesis (Dask)
-> label recovery -> LeRobot export -> PointNet and the RN's features -> RN training -> RN evaluation in
simulation -> LN (A2C pre-trained on the demonstrations, one run per task). See the README for how to
look at the runs.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from prefect import flow

from flows.assets import assets_stage
from flows.evaluate_rn import rn_eval_stage
from flows.export import export_stage
from flows.features import features_stage
from flows.labels import labels_stage
from flows.ln import ln_stage
from flows.plan_trials import trials_stage
from flows.pointnet import pointnet_stage
from flows.stage_pictures import pictures_stage
from flows.synthesize import synthesis_stage
from flows.train_rn import rn_train_stage
from prl import tracking
from prl.config import ConfigError, PipelineConfig, make_config
from prl.version import code_version, git_commit


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
    """The flow body (called inside the Prefect flow): the stages in DAG order under one MLflow parent run."""
    if cfg.render:
        from envs.render_probe import require_rendering

        require_rendering("stage pictures (pass --no-render to skip them)")
    import envs  # noqa: F401  (registers the hand agent and the tasks)

    uri = tracking.configure("prl")
    version = code_version()
    out_dir = cfg.output_dir / f"run-seed{cfg.seed}"
    out_dir.mkdir(parents=True, exist_ok=True)
    print(f"MLflow store: {uri}; outputs: {out_dir}")
    with tracking.parent_run(f"pipeline-{cfg.profile}", params=cfg,
                             tags={"code_version": version, "git_commit": git_commit()}) as parent:
        assets = assets_stage()
        trials = [trials_stage(cfg, assets, name, out_dir, version) for name in cfg.tasks]
        if cfg.render:
            for name in cfg.tasks:
                pictures_stage(assets, name, cfg.seed, out_dir / f"{name}_stages")
        results: dict[str, dict[str, float]] = {t.task: t.rates for t in trials}
        synthesis = synthesis_stage(cfg, trials)
        labels = labels_stage(synthesis, version)
        dataset = export_stage(cfg, synthesis, labels)
        if cfg.train_rn:
            pointnet = pointnet_stage(cfg, assets, version)
            features = features_stage(cfg, dataset, pointnet)
            rn = rn_train_stage(cfg, features, out_dir)
            rn_eval = rn_eval_stage(cfg, rn, cfg.tasks)
            results.update(rn_eval.rates)
            if cfg.train_ln:
                results.update(ln_stage(cfg, features, rn_eval))
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
