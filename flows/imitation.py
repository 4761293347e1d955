"""Imitation in joint space: a LeRobot policy (ACT) trained on an exported dataset's demonstrations of one task, then
rolled out closed loop in the joint-control environment on unseen scenes (``prl.imitation``, ``envs.joint_env``).

    python -m flows.imitation --dataset-root outputs/datasets/hammer-seed0 --task hammer --steps 2000 \\
        --eval-scenes 20 --output-dir outputs/imitation

One MLflow parent run ``imitation-<task>`` with child runs ``imitation-train`` (the config as params, the loss and
ACT's terms per logged step, the loss curve, the policy directory as artifacts, registered as ``prl-imitation``:
lerobot's safetensors and JSON, which load without executing code) and ``imitation-rollout`` (success rate with
its Wilson interval, one row per scene). The evaluation scenes are the LN's (``envs.trials.eval_scene_seeds``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from flows.artifacts import publish_table, rate_row
from prl import tracking
from prl.cli import add_config_arguments, config_overrides
from prl.imitation import ImitationConfig

REGISTERED_MODEL = "prl-imitation"
"""The MLflow registered model of the imitation policies."""


@task(name="imitation-train", task_run_name="imitation-train-{task_name}", cache_policy=NO_CACHE)
def train_task(dataset_root: str, task_name: str, cfg: ImitationConfig, out_dir: str, demos: int | None
               ) -> dict[str, Any]:
    """Train the policy on the dataset's first ``demos`` episodes of ``task_name`` (all when None), in its own
    MLflow child run (nested in the active one); the policy is registered as ``prl-imitation``."""
    import mlflow  # heavy: mlflow
    from mlflow import MlflowClient

    from prl.imitation import task_episodes, train_imitation
    from prl.plots import plot_learning_curves

    episodes = task_episodes(dataset_root, task_name, demos)
    with tracking.child_run("imitation-train", params=cfg) as run:
        mlflow.log_params({"dataset_root": dataset_root, "task": task_name, "episodes": len(episodes)})

        def log(row: dict[str, float]) -> None:
            mlflow.log_metrics({f"imitation/{k}": v for k, v in row.items() if k != "step"}, step=int(row["step"]))

        result = train_imitation(dataset_root, cfg, out_dir, episodes, on_log=log)
        mlflow.log_metrics({"imitation/frames": result.frames, "imitation/train_seconds": result.seconds})
        curve = Path(out_dir) / "imitation_loss.png"
        plot_learning_curves({cfg.policy: [result.losses]}, "step", "loss", curve,
                             title=f"{task_name}: {cfg.policy} training loss", x_label="gradient step")
        mlflow.log_artifact(str(curve))
        mlflow.log_artifacts(str(result.policy_dir), "policy")
        client = MlflowClient()
        if not client.search_registered_models(f"name='{REGISTERED_MODEL}'"):
            client.create_registered_model(REGISTERED_MODEL)
        version = client.create_model_version(REGISTERED_MODEL, source=f"{run.info.artifact_uri}/policy",
                                               run_id=run.info.run_id, tags={"task": task_name})
        print(f"{task_name}: {cfg.policy} trained {cfg.steps} steps on {len(episodes)} demos ({result.frames} frames) "
              f"in {result.seconds / 60:.1f} min, final loss {result.losses[-1]['loss']:.4f}; registered as "
              f"{REGISTERED_MODEL} version {version.version}")
    return {"policy_dir": str(result.policy_dir), "losses": result.losses, "episodes": len(episodes),
            "seconds": result.seconds}


@task(name="imitation-rollout", task_run_name="imitation-rollout-{task_name}", cache_policy=NO_CACHE)
def rollout_task(policy_dir: str, task_name: str, seeds: list[int]) -> dict[str, Any]:
    """Roll the saved policy out on the scene of each seed, in its own MLflow child run (nested in the active one);
    the successes and each scene's outcome."""
    import mlflow  # heavy: mlflow

    from envs.joint_env import run_target_policy  # heavy: loads the simulator
    from prl.imitation import ImitationActor
    from prl.stats import format_rate, wilson_interval

    with tracking.child_run("imitation-rollout", params={"policy_dir": policy_dir, "task": task_name,
                                                         "scenes": len(seeds), "first_seed": seeds[0]}):
        outcomes = run_target_policy(task_name, ImitationActor(policy_dir), seeds)
        k, n = sum(o.success for o in outcomes), len(outcomes)
        lo, hi = wilson_interval(k, n)
        mlflow.log_metrics({"imitation/success_rate": k / n, "imitation/ci95_low": lo, "imitation/ci95_high": hi,
                            "imitation/errors": sum(bool(o.error) for o in outcomes)})
        mlflow.log_table({"seed": [o.seed for o in outcomes], "success": [o.success for o in outcomes],
                          "measure": [o.measure for o in outcomes]}, "rollout_outcomes.json")
        publish_table(f"imitation-rollout-{task_name}", [rate_row(k, n, task=task_name)],
                      "Imitation policy rolled out in the joint-control environment")
        print(f"{task_name} imitation rollout: {format_rate(k, n)}")
    return {"successes": k, "n": n, "outcomes": [dataclasses.asdict(o) for o in outcomes]}


def check_inputs(dataset_root: str, task_name: str, demos: int | None, eval_scenes: int) -> None:
    """ValueError naming an unknown task, a task the dataset does not hold, a feature the policy reads that the
    dataset lacks (one exported before ``observation.environment_state``), or a bad count; FileNotFoundError naming
    a dataset without scene records."""
    from envs.tasks import task_class  # heavy: loads the simulator
    from prl.export_schema import require_feature
    from prl.imitation import IMITATION_INPUTS, task_episodes

    task_class(task_name)
    if demos is not None and demos < 1:
        raise ValueError(f"demos must be >= 1 (or left out for all), got {demos}")
    if eval_scenes < 1:
        raise ValueError(f"eval_scenes must be >= 1, got {eval_scenes}")
    task_episodes(dataset_root, task_name, demos)
    features = json.loads((Path(dataset_root) / "meta" / "info.json").read_text())["features"]
    for name in IMITATION_INPUTS:
        require_feature(features, name, dataset_root)


@flow(name="prl-imitation", log_prints=True)
def imitation(dataset_root: str, task_name: str = "hammer", overrides: dict[str, Any] | None = None,
              demos: int | None = None, eval_seed: int = 0, eval_scenes: int = 20,
              output_dir: str = "outputs/imitation") -> dict[str, Any]:
    """Train ``ImitationConfig(**overrides)`` on ``task_name``'s demos of the dataset at ``dataset_root`` and roll it
    out on ``eval_scenes`` scenes of ``eval_seed``; the rollout's successes and the training's losses."""
    from envs.trials import eval_scene_seeds  # heavy: loads the simulator

    cfg = ImitationConfig(**(overrides or {}))
    check_inputs(dataset_root, task_name, demos, eval_scenes)
    out_dir = Path(output_dir) / f"{task_name}-{cfg.policy}-seed{cfg.seed}"
    tracking.configure("prl")
    with tracking.parent_run(f"imitation-{task_name}", params={"dataset_root": dataset_root, "task": task_name},
                             tags={"method": "imitation"}) as run:
        trained = train_task(dataset_root, task_name, cfg, str(out_dir), demos)
        rollout = rollout_task(trained["policy_dir"], task_name, eval_scene_seeds(eval_seed, eval_scenes))
        print(f"MLflow run {run.info.run_id}")
    return {"train": trained, "rollout": rollout}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m flows.imitation", description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset-root", required=True, help="an exported LeRobot dataset with "
                        "observation.environment_state (the pipeline's outputs/datasets/<tasks>-seed<N>)")
    parser.add_argument("--task", default="hammer", help="the task whose demos are imitated and rolled out")
    parser.add_argument("--demos", type=int, default=None, help="the first N demos of the task (default: all)")
    parser.add_argument("--eval-seed", type=int, default=0, help="evaluation scenes' seed (the LN's)")
    parser.add_argument("--eval-scenes", type=int, default=20, help="unseen scenes of the rollout")
    parser.add_argument("--output-dir", default="outputs/imitation", help="where the policy is saved")
    add_config_arguments(parser, ImitationConfig)
    args = parser.parse_args(argv)
    try:  # before any flow run or MLflow run starts
        overrides = config_overrides(args, ImitationConfig)
        ImitationConfig(**overrides)
        check_inputs(args.dataset_root, args.task, args.demos, args.eval_scenes)
    except (ValueError, TypeError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    imitation(args.dataset_root, args.task, overrides, args.demos, args.eval_seed, args.eval_scenes, args.output_dir)
    return 0


if __name__ == "__main__":
    sys.exit(main())
