"""Stage ``pointnet``: the PointNet encoder pre-trained on synthetic shapes, or the checkpoint of an identical
earlier run (child run ``pointnet``)."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from prefect import task
from prefect.cache_policies import NO_CACHE

from flows.check_assets import Assets
from prl import tracking
from prl.config import PipelineConfig
from prl.version import source_version


@dataclass(frozen=True)
class PointNet:
    """A PointNet checkpoint, its training history per epoch, and whether an earlier run's file was reused."""

    path: Path
    history: dict[str, list[float]]
    reused: bool


def _key(*parts: Any) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:12]


POINTNET_SOURCES: tuple[str, ...] = ("prl/pointnet.py", "prl/shapes.py")
"""The modules that decide a trained PointNet (its network, training and synthetic shapes)."""


def pointnet_version() -> str:
    """``prl.version.source_version`` of ``POINTNET_SOURCES``: the code part of a PointNet checkpoint's name. Only
    these files enter it, so a change elsewhere (a task, the synthesis) keeps the checkpoint's name, and the LN
    summaries that record that name stay valid (``flows.ln_results.point_settings``)."""
    return source_version(*POINTNET_SOURCES)


def train_or_reuse_pointnet(epochs: int, n_shapes: int, n_points: int, seed: int, code_version: str,
                            models_dir: Path) -> PointNet:
    """Train the PointNet encoder on synthetic shapes, or reuse the checkpoint of an identical earlier run.

    The checkpoint's name is a key over the PointNet config and ``code_version`` (``pointnet_version()``), so an
    unchanged re-run loads it instead of training (``reused=True``).
    """
    from prl.pointnet import PointNetConfig, save_pointnet, train_pointnet  # heavy: trimesh

    cfg = PointNetConfig(epochs=epochs, n_shapes=n_shapes, n_points=n_points, seed=seed)
    path = Path(models_dir) / f"pointnet-{_key(asdict(cfg), code_version)}.pt"
    history_path = path.with_suffix(".json")
    if path.is_file() and history_path.is_file():
        return PointNet(path, json.loads(history_path.read_text()), True)
    model, history = train_pointnet(cfg)
    save_pointnet(model, cfg, path)
    history_path.write_text(json.dumps(history))
    return PointNet(path, history, False)


@task(name="pointnet", cache_policy=NO_CACHE)
def pointnet_stage(cfg: PipelineConfig, assets: Assets) -> PointNet:
    """Train (or reuse) the PointNet of ``cfg`` into ``cfg.output_dir/models``; log its history per epoch."""
    import mlflow  # heavy: mlflow

    models_dir = cfg.output_dir / "models"
    models_dir.mkdir(parents=True, exist_ok=True)
    with tracking.child_run("pointnet", params={"epochs": cfg.pn_epochs, "shapes": cfg.pn_shapes,
                                                "n_points": cfg.n_points, "plb_n_plans": assets.plb_n_plans}):
        pn = train_or_reuse_pointnet(cfg.pn_epochs, cfg.pn_shapes, cfg.n_points, cfg.seed, pointnet_version(),
                                     models_dir)
        mlflow.log_params({"checkpoint": str(pn.path), "reused": pn.reused})
        for name, values in pn.history.items():
            for step, value in enumerate(values):
                mlflow.log_metric(f"pn/{name}", float(value), step=step)
    print(f"PointNet {'reused' if pn.reused else 'trained'}: {pn.path.name}, "
          + ", ".join(f"{k} {v[-1]:.3f}" for k, v in pn.history.items()))
    return pn
