"""The Learning Network stage: one A2C run ("point") per task, method, demonstration steps and seed.

A point (``LNPoint``) is one MLflow child run: its settings (``prl.ln.LNConfig.params``), the
pre-training losses per minibatch (``ln/pretrain/*``), one row of metrics per A2C update at the
update's timestep (``ln/success_rate``, ``ln/window_success_rate``, ``ln/reward``, ``ln/policy_loss``,
``ln/value_loss``, ``ln/entropy``, ``ln/frames``), the learning-curve plots, the SB3 checkpoint, and the
final policy's deterministic plan executed on the unseen evaluation scenes (``ln/eval/*`` with a 95%
Wilson interval). Variants: ``physics`` (A2C over the Representation Space, pre-trained actor and
critic on ``demo_steps`` demonstrations; 0 is pure RL), ``bc`` (the same with the actor alone
pre-trained), ``joint`` (A2C on 30-D joint targets, ``envs.joint_env``), ``joint_bc`` (the same, its actor first
cloned from the K demonstrations' joint actions and its critic fitted to their returns, ``prl.joint_bc``), and
``physics_gated`` (not the paper's:
the physics method with the reward paid only on success, ``gated_rewards``; the curve's ``ln/reward`` stays the
measure). ``imitation`` is no A2C run: LeRobot's ACT trained on the same K demonstrations' joint actions and rolled
out in the joint-control environment (``run_imitation_point``); its curve is the training loss.

Used by the pipeline's ``ln`` stage (``ln_stage``) and fanned out by ``flows.ablation``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from prefect import task
from prefect.cache_policies import NO_CACHE

from flows.artifacts import publish_table, rate_row
from flows.compute_features import Features
from flows.evaluate_rn import RNEval
from prl import tracking
from prl.atomic import atomic_file, write_atomic
from prl.config import JOINT_A2C_METHODS, LN_METHODS, LNConfig, PipelineConfig
from prl.imitation import ImitationConfig


@dataclass(frozen=True)
class LNPoint:
    """One LN run: a task, a method of ``prl.config.LN_METHODS``, demonstration steps K and a seed."""

    task: str
    method: str = "physics"
    demo_steps: int = 0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.method not in LN_METHODS:
            raise ValueError(f"unknown LN method {self.method!r}; known: {', '.join(LN_METHODS)}")
        if isinstance(self.demo_steps, bool) or not isinstance(self.demo_steps, int) or self.demo_steps < 0:
            raise ValueError(f"demo_steps must be an integer >= 0, got {self.demo_steps!r}")
        if self.method == "joint" and self.demo_steps:
            raise ValueError(f"the joint-control baseline has no demonstration pre-training (demo_steps={self.demo_steps})")
        if self.method in ("bc", "joint_bc", "imitation") and not self.demo_steps:
            raise ValueError(f"the {self.method} method learns from demonstrations alone: give demo_steps > 0")

    @property
    def name(self) -> str:
        """Run name and resume key, e.g. ``ln-hammer-physics-k1280-seed0``."""
        return f"ln-{self.task}-{self.method}-k{self.demo_steps}-seed{self.seed}"


@dataclass(frozen=True)
class LNSetup:
    """What every point of one pipeline run or sweep shares."""

    demo_dir: Path
    """Where ``write_demonstrations`` left each task's ``demos-<task>.npz``."""
    pointnet_path: Path | None
    """The PointNet that encoded the demonstrations' x (the plan env encodes live scenes with it); None where only
    joint control runs."""
    out_dir: Path
    """Checkpoints, curves and point summaries."""
    eval_seeds: tuple[int, ...]
    """Unseen scenes on which each final policy is evaluated (the RN evaluation's)."""
    ln: LNConfig
    """The LN settings of every point; each point sets its own demo_steps, pretrain_mode and seed (``run_point``)."""
    n_points: int = 512
    n_frames: int | None = None
    """Physics frames per plan episode (None: the executor's default)."""
    register: bool = False
    """Register the final policy as the MLflow model ``prl-ln`` (the pipeline does; sweep points do not)."""
    progress: bool = True
    dataset_root: Path | None = None
    """The exported dataset the demonstrations came from: the imitation and joint_bc points learn from its
    episodes."""
    imitation: ImitationConfig = dataclasses.field(default_factory=ImitationConfig)
    """The imitation points' policy and training; each point sets its seed."""


def point_config(point: LNPoint, ln: LNConfig) -> LNConfig:
    """The LN settings of ``point``: ``ln`` with the point's demonstration steps, pre-training mode and seed."""
    return dataclasses.replace(ln, demo_steps=point.demo_steps, seed=point.seed,
                               pretrain_mode="bc" if point.method == "bc" else "actor_critic")


def gated_rewards(rewards: np.ndarray, infos: Sequence[dict[str, Any]]) -> np.ndarray:
    """The ``physics_gated`` method's rewards: each episode's reward (the task's measure) where its ``info`` says
    the task's success rule held, else 0. The paper pays the measure alone (d, N, theta); where a task's rule asks
    more than its measure does (the unscrew's grip of the cap), that reward can pay most for plans the rule
    refuses. The demonstrations all succeeded, so their rewards, the critic's pre-training targets, are unchanged."""
    rewards = np.asarray(rewards)
    if len(infos) != len(rewards):
        raise ValueError(f"{len(rewards)} rewards but {len(infos)} infos")
    return rewards * np.array([bool(info.get("success", False)) for info in infos], dtype=rewards.dtype)


def success_gated(venv: Any) -> Any:
    """``venv`` (an SB3 vector env of plan environments) with its rewards passed through ``gated_rewards``."""
    from stable_baselines3.common.vec_env import VecEnvWrapper  # heavy: SB3

    class SuccessGated(VecEnvWrapper):
        def reset(self) -> Any:
            return self.venv.reset()

        def step_wait(self) -> Any:
            obs, rewards, dones, infos = self.venv.step_wait()
            return obs, gated_rewards(rewards, infos), dones, infos

    return SuccessGated(venv)


def write_demonstrations(demo_dir: Path, tasks: list[str], data: dict[str, Any]) -> dict[str, int]:
    """Write each task's demonstration transitions (``prl.ln.task_demonstrations`` of the RN features ``data``,
    as ``flows.compute_features.rn_features`` returns them) to ``demo_dir/demos-<task>.npz``; the count per task."""
    from envs.tasks import task_class  # heavy: loads the simulator
    from prl.ln import task_demonstrations

    demo_dir.mkdir(parents=True, exist_ok=True)
    counts = {}
    for name in tasks:
        demos = task_demonstrations(name, task_class(name).measure_key, data["x"], data["plan"], data["tasks"],
                                    data["outcomes"], data.get("weights"))
        with atomic_file(demo_dir / f"demos-{name}.npz", "wb") as fh:
            np.savez(fh, x=demos.x, plan=demos.plan, reward=demos.reward, weight=demos.weight)
        counts[name] = len(demos.x)
    return counts


def read_demonstrations(demo_dir: Path, task_name: str) -> Any:
    """The ``Demonstrations`` of ``write_demonstrations`` for ``task_name``; a clear error when missing."""
    from prl.ln import Demonstrations  # heavy: torch (stable-baselines3)

    path = Path(demo_dir) / f"demos-{task_name}.npz"
    if not path.is_file():
        raise FileNotFoundError(f"no demonstrations of task {task_name!r} at {str(path)!r} "
                                f"(the dataset has none, or the RN features were not written)")
    with np.load(path) as f:
        return Demonstrations(f["x"], f["plan"], f["reward"], f["weight"] if "weight" in f.files else None)


def _log_rows(rows: list[dict[str, float]], prefix: str, step_key: str | None) -> None:
    import mlflow  # heavy: mlflow

    for i, row in enumerate(rows):
        step = int(row[step_key]) if step_key else i
        mlflow.log_metrics({f"{prefix}/{k}": float(v) for k, v in row.items()}, step=step)


def run_point(point: LNPoint, setup: LNSetup, parent_run_id: str | None = None) -> dict[str, Any]:
    """Pre-train (if K > 0), train and evaluate one LN point inside its own MLflow child run (under the active
    run, or ``parent_run_id``); returns its summary (also written to ``setup.out_dir/<name>.json``)."""
    import mlflow  # heavy: mlflow

    from envs.joint_env import JointControlEnv
    from envs.plan_env import PlanEnv
    from envs.replay import replayed_demonstrations
    from envs.tasks import fast_resets, task_class
    from envs.vec_env import make_vec_env
    from prl.imitation import drawn_episodes, task_episodes
    from prl.joint_bc import pretrain_joint
    from prl.ln import make_ln, pretrain, save_ln, train_ln
    from prl.plots import plot_learning_curves
    from prl.rn_train import feature_stats

    task_class(point.task)  # ValueError naming an unknown task before anything runs
    if point.method == "imitation":
        return run_imitation_point(point, setup, parent_run_id)
    cfg = point_config(point, setup.ln)
    joint = point.method in JOINT_A2C_METHODS
    demos = None if joint else read_demonstrations(setup.demo_dir, point.task)
    episodes = drawn_episodes(dataset_of(point, setup), point.task, point.demo_steps, point.seed) \
        if point.method == "joint_bc" else []  # K beyond the dataset's episodes: an error now
    served = demos.take(point.demo_steps, point.seed) if demos is not None else None  # K beyond the demos: error now
    setup.out_dir.mkdir(parents=True, exist_ok=True)
    params = {**cfg.params(), **{f"point.{k}": v for k, v in asdict(point).items()},
              "pointnet": str(setup.pointnet_path), "eval_scenes": len(setup.eval_seeds),
              "demonstrations_available": len(demos.x) if demos is not None else
              len(task_episodes(setup.dataset_root, point.task)) if episodes else 0,
              "demo_target": "commanded plan and its measured reward"}
    t0 = time.perf_counter()
    with tracking.child_run(point.name, params=params, parent_run_id=parent_run_id) as run:
        mlflow.set_tags({"ln_point": point.name, "ln_method": point.method, "task": point.task})
        env_kwargs = {} if joint else {"pointnet_path": setup.pointnet_path, "n_points": setup.n_points,
                                       **({"n_frames": setup.n_frames} if setup.n_frames else {})}
        env = make_vec_env(JointControlEnv if joint else PlanEnv, point.task, cfg.n_envs, run_seed=point.seed, **env_kwargs)
        try:
            if point.method == "physics_gated":
                env = success_gated(env)  # its close() closes the environments it wraps
            stats = feature_stats(demos.x) if demos is not None else (None, None)
            model = make_ln(env, cfg, *stats)
            pre_rows = [] if served is None else pretrain(model, served, cfg.pretrain_mode, cfg.pretrain_epochs,
                                                          batch_size=cfg.steps_per_update, seed=cfg.seed)
            if episodes:
                cloned = replayed_demonstrations(setup.dataset_root, point.task, episodes, cfg.gamma, setup.progress)
                pre_rows = pretrain_joint(model, cloned, cfg.pretrain_epochs, batch_size=cfg.steps_per_update,
                                          seed=cfg.seed)
            _log_rows(pre_rows, "ln/pretrain", None)
            with fast_resets():
                rows = train_ln(model, cfg.timesteps, progress=setup.progress, desc=point.name,
                                on_update=lambda row: _log_rows([row], "ln", "timesteps"))
        finally:
            env.close()
        train_s = time.perf_counter() - t0
        ckpt = save_ln(model, setup.out_dir / f"{point.name}.zip")
        mlflow.log_artifact(str(ckpt))
        check_x = served.x[:64] if served is not None and len(served.x) else \
            np.random.default_rng(0).normal(size=(16, *model.observation_space.shape)).astype(np.float32)
        if setup.register:
            mlflow.log_metric("registered_reload_action_mismatches", register_policy(model, check_x))
        t_eval = time.perf_counter()
        evaluation = evaluate_and_log(point, model, setup)
        eval_s = time.perf_counter() - t_eval
        mlflow.log_metrics({"train_seconds": train_s, "eval_seconds": eval_s,
                            "timesteps_per_second": cfg.timesteps / train_s if train_s > 0 else 0.0})
        for x_key in ("timesteps", "frames"):
            fig = plot_learning_curves({point.method: [rows]}, x_key, "window_success_rate",
                                       setup.out_dir / f"{point.name}-{x_key}.png", title=point.name)
            mlflow.log_figure(fig, f"curves/{point.name}-{x_key}.png")
        summary = {"point": asdict(point), "name": point.name, "run_id": run.info.run_id, "rows": rows,
                   "pretrain": pre_rows, "checkpoint": str(ckpt), "train_seconds": train_s, "eval_seconds": eval_s,
                   "eval": evaluation}
        write_point_summary(summary, setup.out_dir)
    return summary


def dataset_of(point: LNPoint, setup: LNSetup) -> Path:
    """The dataset whose episodes ``point`` learns from; ValueError naming the point when the setup has none."""
    if setup.dataset_root is None:
        raise ValueError(f"point {point.name} learns from the dataset's episodes: the sweep needs a dataset_root")
    return Path(setup.dataset_root)


def run_imitation_point(point: LNPoint, setup: LNSetup, parent_run_id: str | None = None) -> dict[str, Any]:
    """An ``imitation`` point of the LN sweep: ``setup.imitation``'s policy trained on the dataset episodes of the
    K demonstrations that the plan-space points of its seed are pre-trained on (``prl.imitation.drawn_episodes``),
    then rolled out closed loop in the joint-control environment on the evaluation scenes, all in its own MLflow
    child run (tagged as the LN points are). Returns its summary as ``run_point`` does: ``rows`` empty (no RL
    update), ``loss`` the training loss per logged step, ``checkpoint`` the saved policy's directory. ValueError
    naming a setup without a dataset, or a K beyond it."""
    import mlflow  # heavy: mlflow

    from envs.joint_env import run_target_policy  # heavy: loads the simulator
    from prl.imitation import ImitationActor, drawn_episodes, train_imitation
    from prl.plots import plot_learning_curves

    episodes = drawn_episodes(dataset_of(point, setup), point.task, point.demo_steps, point.seed)
    cfg = dataclasses.replace(setup.imitation, seed=point.seed)
    out_dir = Path(setup.out_dir) / point.name
    params = {**{f"imitation.{k}": v for k, v in dataclasses.asdict(cfg).items()},
              **{f"point.{k}": v for k, v in dataclasses.asdict(point).items()},
              "dataset_root": str(setup.dataset_root), "episodes": len(episodes),
              "eval_scenes": len(setup.eval_seeds)}
    t0 = time.perf_counter()
    with tracking.child_run(point.name, params=params, parent_run_id=parent_run_id) as run:
        mlflow.set_tags({"ln_point": point.name, "ln_method": point.method, "task": point.task})

        def log(row: dict[str, float]) -> None:
            mlflow.log_metrics({**{f"imitation/{k}": v for k, v in row.items() if k != "step"},
                                "imitation/steps": float(row["step"])}, step=int(row["step"]))

        result = train_imitation(setup.dataset_root, cfg, out_dir, episodes, progress=setup.progress, on_log=log)
        train_s = time.perf_counter() - t0
        mlflow.log_artifacts(str(result.policy_dir), "policy")
        fig = plot_learning_curves({cfg.policy: [result.losses]}, "step", "loss", out_dir / f"{point.name}-loss.png",
                                   title=f"{point.name}: training loss", x_label="gradient step")
        mlflow.log_figure(fig, f"curves/{point.name}-loss.png")
        t_eval = time.perf_counter()
        evaluation = log_evaluation(run_target_policy(point.task, ImitationActor(result.policy_dir),
                                                      list(setup.eval_seeds), progress=setup.progress))
        eval_s = time.perf_counter() - t_eval
        mlflow.log_metrics({"train_seconds": train_s, "eval_seconds": eval_s})
        summary = {"point": dataclasses.asdict(point), "name": point.name, "run_id": run.info.run_id, "rows": [],
                   "loss": result.losses, "pretrain": [], "checkpoint": str(result.policy_dir),
                   "train_seconds": train_s, "eval_seconds": eval_s, "eval": evaluation}
        write_point_summary(summary, setup.out_dir)
    return summary


def write_point_summary(summary: dict[str, Any], out_dir: Path) -> None:
    """Log the point's summary to its (active) run and write it to ``out_dir/<name>.json`` atomically."""
    import mlflow  # heavy: mlflow

    mlflow.log_dict(summary, f"{summary['name']}.json")
    write_atomic(out_dir / f"{summary['name']}.json", json.dumps(summary))


def evaluate_and_log(point: LNPoint, model: Any, setup: LNSetup) -> dict[str, Any]:
    """``evaluate_policy``, its ``ln/eval/*`` metrics logged to the active run; returns the summary's ``eval``."""
    return log_evaluation(evaluate_policy(point, model, setup))


def log_evaluation(outcomes: Sequence[Any]) -> dict[str, Any]:
    """The summary's ``eval`` of a final policy's outcomes on the evaluation scenes, its ``ln/eval/*`` metrics
    logged to the active run."""
    import mlflow  # heavy: mlflow

    from prl.stats import wilson_interval

    k, n = sum(o.success for o in outcomes), len(outcomes)
    lo, hi = wilson_interval(k, n) if n else (0.0, 0.0)
    mlflow.log_metrics({"ln/eval/success_rate": k / max(n, 1), "ln/eval/ci95_low": lo, "ln/eval/ci95_high": hi,
                        "ln/eval/mean_measure": float(np.mean([o.measure for o in outcomes])) if n else 0.0,
                        "ln/eval/errors": sum(bool(o.error) for o in outcomes)})
    return {"successes": k, "n": n, "ci95": [lo, hi],
            "outcomes": [{"seed": o.seed, "plan": list(o.plan), "success": o.success, "measure": o.measure,
                          "error": o.error} for o in outcomes]}


def reevaluate_point(summary: dict[str, Any], setup: LNSetup) -> dict[str, Any]:
    """Evaluate a finished point's saved final policy again under today's task code (after a change to a task's
    success criterion), without retraining: the new ``ln/eval/*`` values are logged to the point's run, the
    summary's ``eval`` is replaced (the one it replaces kept as ``eval_before``) and rewritten."""
    import mlflow  # heavy: mlflow

    from prl.ln import load_ln
    from prl.version import code_version

    point = LNPoint(**summary["point"])
    model = load_ln(summary["checkpoint"])  # FileNotFoundError naming a missing checkpoint
    with mlflow.start_run(run_id=summary["run_id"], nested=mlflow.active_run() is not None):
        evaluation = evaluate_and_log(point, model, setup)
        mlflow.set_tag("reevaluated_at_code", code_version())
        summary = {**summary, "eval": evaluation, "eval_before": summary.get("eval_before", summary["eval"])}
        write_point_summary(summary, setup.out_dir)
    return summary


def evaluate_policy(point: LNPoint, model: Any, setup: LNSetup) -> list[Any]:
    """The final policy's deterministic action on each evaluation scene, executed in simulation."""
    from envs.joint_env import run_joint_policy  # heavy: loads the simulator
    from envs.trials import run_policy
    from prl.ln import ln_policy
    from prl.plb import load_plb
    from prl.pointnet import load_pointnet

    seeds = list(setup.eval_seeds)
    if point.method in JOINT_A2C_METHODS:
        return run_joint_policy(point.task, model.policy, seeds, progress=setup.progress)
    policy = ln_policy(model.policy, load_pointnet(setup.pointnet_path), point.task, load_plb().texts(point.task),
                       seeds, setup.n_points)
    kwargs = {"n_frames": setup.n_frames} if setup.n_frames else {}
    return run_policy(point.task, policy, seeds, progress=setup.progress, desc=f"{point.name} plans", **kwargs)


def register_policy(model: Any, x_check: np.ndarray) -> int:
    """Log the policy's deterministic plan (``prl.ln.PlanActor``) as an MLflow model in the ``pt2`` format (no
    pickle: ``prl.tracking.log_exported_model``) registered as ``prl-ln``, reload it without unpickling, and
    return how many of its plans on ``x_check`` differ from the in-memory SB3 policy's deterministic actions
    (0 expected)."""
    import torch  # heavy: torch

    from prl.ln import PlanActor

    x = np.asarray(x_check, np.float32)
    before = np.asarray(model.policy.predict(x, deterministic=True)[0]).reshape(len(x), -1)
    example = np.resize(x, (max(2, min(8, len(x))), x.shape[1]))  # >= 2 rows: the batch size stays free
    info = tracking.log_exported_model(PlanActor(model.policy), "ln", example, "prl-ln")
    reloaded = tracking.load_exported_model(info.model_uri)
    with torch.no_grad():
        again = reloaded(torch.as_tensor(x)).numpy()
    return int(np.sum(np.any(again != before, axis=1)))


@task(name="ln", task_run_name="{point.name}", cache_policy=NO_CACHE)
def ln_point(point: LNPoint, setup: LNSetup, parent_run_id: str | None = None) -> dict[str, Any]:
    """Prefect task of ``run_point`` (a Dask worker runs it in the ablation sweep, pointed at the store here)."""
    if parent_run_id is not None:
        tracking.configure("prl")
    return run_point(point, setup, parent_run_id)


@task(name="ln-reevaluate", task_run_name="reevaluate-{summary[name]}", cache_policy=NO_CACHE)
def ln_reevaluate(summary: dict[str, Any], setup: LNSetup) -> dict[str, Any]:
    """Prefect task of ``reevaluate_point`` (a Dask worker runs it in the sweep, pointed at the store here)."""
    tracking.configure("prl")
    return reevaluate_point(summary, setup)


@task(name="ln-stage", task_run_name="ln", cache_policy=NO_CACHE)
def ln_stage(cfg: PipelineConfig, features: Features, rn_eval: RNEval) -> dict[str, dict[str, float]]:
    """Stage ``ln`` of the pipeline: one physics-guided LN point per task (child run ``ln-<task>-physics-k<K>-seed<N>``),
    pre-trained on ``cfg.ln.demo_steps`` of the dataset's demonstrations and evaluated on the RN evaluation's
    unseen scenes; each final policy registered as ``prl-ln``. Returns the evaluation's success rate per task."""
    tasks = list(dict.fromkeys(features.data["tasks"]))
    root = cfg.output_dir / "ln" / f"seed{cfg.seed}"
    setup = LNSetup(demo_dir=root / "demos", pointnet_path=features.pointnet_path, out_dir=root / "points",
                    eval_seeds=rn_eval.eval_seeds, ln=cfg.ln, n_points=cfg.n_points, n_frames=cfg.episode_frames,
                    register=True)
    write_demonstrations(setup.demo_dir, tasks, features.data)
    results = {}
    table = []
    for name in tasks:
        summary = ln_point(LNPoint(name, "physics", cfg.ln.demo_steps, cfg.seed), setup)
        ev, rows = summary["eval"], summary["rows"]
        print(f"{name} LN ({cfg.ln.timesteps} timesteps, pre-trained on {cfg.ln.demo_steps} demos): training success "
              f"{rows[-1]['success_rate'] if rows else float('nan'):.2f} in the last update; deterministic plan "
              f"{ev['successes']}/{ev['n']} on unseen scenes (95% CI {ev['ci95'][0]:.2f}-{ev['ci95'][1]:.2f})")
        results[f"{name}/ln"] = {"success_rate": ev["successes"] / max(ev["n"], 1)}
        table.append(rate_row(ev["successes"], ev["n"], task=name, split="train_ranges", plan="ln deterministic"))
    publish_table("ln-success", table, f"The LN's deterministic plan after {cfg.ln.timesteps} RL timesteps, "
                  f"pre-trained on {cfg.ln.demo_steps} demos, on the RN evaluation's unseen scenes")
    return results
