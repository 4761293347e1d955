"""Stage ``features``: the RN's input x = [x_manip | TE | PN(tool) | PN(object)] of every episode of the exported
dataset, with its targets and scene identity (child run ``features``)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from prefect import task
from prefect.cache_policies import NO_CACHE

from flows.export_dataset import Dataset
from flows.train_pointnet import PointNet
from prl import tracking
from prl.config import PipelineConfig


@dataclass(frozen=True)
class Features:
    """``rn_features`` of a dataset and the PointNet that encoded its point clouds."""

    data: dict[str, Any]
    pointnet_path: Path


def rn_features(dataset_root: Path, repo_id: str, pointnet_path: Path, n_points: int) -> dict[str, Any]:
    """x, targets and scene identity of every episode of the exported dataset."""
    from prl.features import episode_features, read_episodes  # heavy: trimesh
    from prl.pointnet import load_pointnet

    episodes = read_episodes(dataset_root, repo_id)
    x = episode_features(episodes, load_pointnet(pointnet_path), n_points)
    return {"x": x, "plan": episodes.plan, "label": episodes.label, "seeds": episodes.seeds,
            "tasks": list(episodes.tasks), "texts": list(episodes.texts), "outcomes": list(episodes.outcomes),
            "families": scene_families(episodes.scene_params),
            "weights": episodes.weights if episodes.weights is not None else np.ones(len(episodes))}


def scene_families(scene_params: list[dict[str, float]] | tuple[dict[str, float], ...]) -> list[int]:
    """Each episode's scene family (a mixed variant's ``scene_params["family"]``), -1 for a task without families:
    for the reports per family (Fig 7, accuracy); never an input of the RN."""
    return [int(p["family"]) if "family" in p else -1 for p in scene_params]


@task(name="features", cache_policy=NO_CACHE)
def features_stage(cfg: PipelineConfig, dataset: Dataset, pointnet: PointNet) -> Features:
    """Read the dataset back with ``lerobot`` and encode every episode; log the episodes per task and x's width."""
    import mlflow  # heavy: mlflow

    from prl.features import FEATURE_LAYOUT

    with tracking.child_run("features", params={"dataset_root": str(dataset.root), "repo_id": dataset.repo_id,
                                                "pointnet": pointnet.path.name,
                                                "feature_layout": FEATURE_LAYOUT.to_json()}):
        data = rn_features(dataset.root, dataset.repo_id, pointnet.path, cfg.n_points)
        mlflow.log_metrics({"x_dim": int(data["x"].shape[1]),
                            **{f"{t}/episodes": n for t, n in Counter(data["tasks"]).items()}})
    return Features(data, pointnet.path)
