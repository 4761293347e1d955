"""Prefect tasks of the Representation Network: PointNet pre-training, RN training, RN evaluation in simulation.

Thin over ``prl.pointnet``, ``prl.features``, ``prl.rn`` and ``envs.trials``; MLflow logging happens
in ``flows.full_pipeline``, which calls these inside its child runs.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from prefect import task
from prefect.cache_policies import NO_CACHE


def _key(*parts: Any) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:12]


@task(name="train-pointnet", cache_policy=NO_CACHE)
def train_pointnet_stage(epochs: int, n_shapes: int, n_points: int, seed: int, code_version: str,
                         models_dir: Path) -> tuple[Path, dict[str, list[float]], bool]:
    """Train the PointNet encoder on synthetic shapes, or reuse the checkpoint of an identical earlier run.

    The checkpoint's name is a key over the PointNet config and ``code_version``, so an unchanged
    re-run loads it instead of training (returns ``reused=True``). Returns (checkpoint, history, reused).
    """
    from prl.pointnet import PointNetConfig, save_pointnet, train_pointnet

    cfg = PointNetConfig(epochs=epochs, n_shapes=n_shapes, n_points=n_points, seed=seed)
    path = Path(models_dir) / f"pointnet-{_key(asdict(cfg), code_version)}.pt"
    history_path = path.with_suffix(".json")
    if path.is_file() and history_path.is_file():
        return path, json.loads(history_path.read_text()), True
    model, history = train_pointnet(cfg)
    save_pointnet(model, cfg, path)
    history_path.write_text(json.dumps(history))
    return path, history, False


@task(name="rn-features", cache_policy=NO_CACHE)
def rn_features(dataset_root: Path, repo_id: str, pointnet_path: Path, n_points: int) -> dict[str, Any]:
    """x, targets and scene identity of every episode of the exported dataset."""
    from prl.features import episode_features, read_episodes
    from prl.pointnet import load_pointnet

    episodes = read_episodes(dataset_root, repo_id)
    x = episode_features(episodes, load_pointnet(pointnet_path), n_points)
    return {"x": x, "plan": episodes.plan, "label": episodes.label, "seeds": episodes.seeds,
            "tasks": list(episodes.tasks), "texts": list(episodes.texts), "outcomes": list(episodes.outcomes)}


#: How the RN's per-dimension distributions become one plan (each evaluated in simulation): 'rn' the
#: per-dimension argmax (the paper), 'rn_library' the most probable plan among the task's demonstrated
#: plans, 'rn_success' the same divided by the sampling prior (ranks by success probability); see
#: ``prl.rn.library_plan``.
DECODINGS: tuple[str, ...] = ("rn", "rn_library", "rn_success")
#: Plan kinds run next to the RN decodings on the same scenes: a plan sampled from the task prior, the expert plan.
BASELINES: tuple[str, ...] = ("prior", "expert")


def decoding(model: Any, task_name: str, kind: str) -> tuple[np.ndarray | None, tuple[np.ndarray, ...] | None]:
    """(library, prior) of ``predict_plan`` for a decoding of ``DECODINGS``; a clear error for an unknown one or
    a model without a plan library for the task.

    'rn_success' divides by the prior stored with the model (``model.plan_priors``); a checkpoint written
    before priors were stored falls back to the task's prior in the current PLB catalogue."""
    from prl.plb import load_plb

    if kind not in DECODINGS:
        raise ValueError(f"unknown RN decoding {kind!r}; known: {', '.join(DECODINGS)}")
    if kind == "rn":
        return None, None
    if task_name not in model.plan_libraries:
        raise ValueError(f"decoding {kind!r} needs a plan library for task {task_name!r}; the model has "
                         f"{sorted(model.plan_libraries) or 'none'}")
    if kind == "rn_library":
        return model.plan_libraries[task_name], None
    prior = model.plan_priors.get(task_name) or load_plb().prior(task_name)
    return model.plan_libraries[task_name], prior


def check_pointnet(model: Any, pointnet_path: Path) -> None:
    """ValueError when the RN records the PointNet it was trained with and ``pointnet_path`` is another one
    (its features would not be the ones the RN learned from)."""
    from prl.version import file_digest

    digest = file_digest(pointnet_path)
    if model.pointnet_sha256 is not None and digest != model.pointnet_sha256:
        raise ValueError(f"PointNet checkpoint {pointnet_path} (sha256 {digest[:12]}) is not the one this RN was "
                         f"trained with (sha256 {model.pointnet_sha256[:12]})")


def rn_policy(model: Any, pointnet: Any, task_name: str, texts: list[str], seeds: list[int], n_points: int,
              kind: str = "rn"):
    """An ``envs.trials.Policy`` choosing the RN's plan from the live scene's features, decoded as ``kind``
    (one of ``DECODINGS``).

    Trial ``i`` runs on the scene of ``seeds[i]``; its task sentence cycles through the task's
    phrasings in the PLB catalogue.
    """
    from prl.features import scene_features
    from prl.rn import predict_plan

    library, prior = decoding(model, task_name, kind)

    def choose(i: int, env: Any, x_manip: np.ndarray) -> list[int]:
        x = scene_features(task_name, int(seeds[i]), dict(env.scene_params), x_manip, texts[i % len(texts)],
                           pointnet, n_points)
        return predict_plan(model, x, library, prior)[0].tolist()

    return choose


@task(name="rn-eval-sim", task_run_name="rn-eval-{task_name}-x{randomization}", cache_policy=NO_CACHE)
def evaluate_in_sim(rn_path: Path, pointnet_path: Path, task_name: str, seeds: list[int], n_points: int,
                    n_frames: int, randomization: float, prior_seed: int,
                    decodings: tuple[str, ...] = DECODINGS) -> dict[str, list]:
    """On each of ``seeds``' scenes execute the RN's plan under each of ``decodings`` and two baselines: a
    plan sampled from the task prior the demos were drawn from ('prior') and the task's hand-written
    expert plan, the same on every scene ('expert'); the outcomes of each, keyed by decoding or baseline."""
    from envs.trials import plan_set, run_policy, run_trials
    from prl.plb import load_plb
    from prl.pointnet import load_pointnet
    from prl.rn import load_rn

    model = load_rn(rn_path)
    check_pointnet(model, pointnet_path)
    texts = list(load_plb().texts(task_name))
    pointnet = load_pointnet(pointnet_path)
    out: dict[str, list] = {}
    for kind in decodings:
        policy = rn_policy(model, pointnet, task_name, texts, seeds, n_points, kind)
        out[kind] = run_policy(task_name, policy, seeds, n_frames=n_frames, randomization=randomization,
                               desc=f"{task_name} {kind} plans (x{randomization:g} ranges)")
    for kind, plan_seed in zip(BASELINES, (prior_seed, 0), strict=True):
        out[kind] = run_trials(task_name, plan_set(task_name, kind, len(seeds), plan_seed), seeds,
                               n_frames=n_frames, randomization=randomization)
    return out
