"""Stage ``rn-train``: the Representation Network trained on the dataset's features, split by scene seed, and
registered as the MLflow model ``prl-rn`` (child run ``rn-train``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from prefect import task
from prefect.cache_policies import NO_CACHE

from flows.compute_features import Features
from prl import tracking
from prl.config import PipelineConfig
from prl.plb import load_plb
from prl.stats import effective_sample_size


@dataclass(frozen=True)
class TrainedRN:
    """The RN checkpoint, the PointNet its inputs were encoded with, and its held-out accuracy per dimension."""

    rn_path: Path
    pointnet_path: Path
    val_accuracy: dict[str, float]


@task(name="rn-train", cache_policy=NO_CACHE)
def rn_train_stage(cfg: PipelineConfig, features: Features, out_dir: Path) -> TrainedRN:
    """Train the RN on the scenes not held out (``cfg.rn_val_fraction`` of the seeds are), log its curves,
    per-dimension accuracy, Fig 7 (``rn_probabilities.png``) and the task plan libraries, save and register it."""
    import mlflow  # heavy: mlflow

    from prl.features import FEATURE_LAYOUT, split_by_seed
    from prl.plots import plot_rn_probabilities
    from prl.rn import RNConfig
    from prl.rn_checkpoint import save_rn
    from prl.rn_decode import per_dim_accuracy, plan_libraries, predict_proba
    from prl.rn_train import train_rn
    from prl.version import file_digest

    plb = load_plb()
    data = features.data
    rn_cfg = RNConfig(epochs=cfg.rn_epochs, seed=cfg.seed)
    with tracking.child_run("rn-train", params={**{f"rn.{k}": v for k, v in vars(rn_cfg).items()},
                                                "val_fraction": cfg.rn_val_fraction, "target": "commanded plan",
                                                "weighted": cfg.rn_weighted,
                                                "feature_layout": FEATURE_LAYOUT.to_json()}):
        x, y = data["x"], data["plan"]
        train, val = split_by_seed(data["seeds"], cfg.rn_val_fraction, salt=cfg.seed)
        mlflow.log_metrics({"n_train": len(train), "n_val": len(val)})

        def log_epoch(epoch: int, metrics: dict[str, float]) -> None:
            mlflow.log_metrics({k: float(v) for k, v in metrics.items()}, step=epoch)

        weights = np.asarray(data.get("weights", np.ones(len(x))))  # prior / proposal of each demo (prl.proposal)
        mlflow.log_metrics({"demo_weight_max": float(weights.max()), "demo_weight_ess": effective_sample_size(weights)})
        w_train = weights[train] if cfg.rn_weighted else None  # None: the demos as drawn (--no-rn-weighted)
        model, _ = train_rn(x[train], y[train], rn_cfg, x[val], y[val], on_epoch=log_epoch, w_train=w_train)
        acc = dict(zip(plb.dim_names, (float(a) for a in per_dim_accuracy(model, x[val], y[val])), strict=True))
        mlflow.log_metrics({f"val_accuracy/{name}": a for name, a in acc.items()})
        print("RN validation accuracy: " + ", ".join(f"{n} {a:.2f}" for n, a in acc.items()))
        groups = figure_groups(data["tasks"], data["families"])
        counts = demo_counts(groups, weights)
        mlflow.log_metrics({f"{key}/{name.replace(' ', '_')}": v for name, (n, ess) in counts.items()
                            for key, v in (("n_demos", n), ("demo_weight_ess", ess))})
        print("RN demos (effective sample size of their weights): "
              + ", ".join(f"{name} {n} ({ess:.0f})" for name, (n, ess) in counts.items()))
        val_groups = {name: np.intersect1d(rows, val) for name, rows in groups.items()}
        val_groups = {name: rows for name, rows in val_groups.items() if len(rows)}
        for name, rows in val_groups.items():
            if " family " in name:  # what a mixed variant's RN reads of each family
                mlflow.log_metrics({f"val_accuracy/{name.replace(' ', '_')}/{dim}": float(a) for dim, a in zip(
                    plb.dim_names, per_dim_accuracy(model, x[rows], y[rows]), strict=True)})
        probs_by_task = {name: predict_proba(model, x[rows]) for name, rows in val_groups.items()}
        fig = plot_rn_probabilities(probs_by_task, plb.dim_names, [d.choices for d in plb.dims],
                                    out_dir / "rn_probabilities.png",
                                    weights_by_task={name: weights[rows] for name, rows in val_groups.items()})
        mlflow.log_figure(fig, "rn_probabilities.png")
        model.plan_libraries = plan_libraries(y[train], [data["tasks"][i] for i in train])  # rn-eval's decodings
        model.plan_priors = {t: plb.prior(t) for t in model.plan_libraries}  # the catalogue prior synthesis samples
        model.pointnet_sha256 = file_digest(features.pointnet_path)
        mlflow.log_metrics({f"{t}/plan_library_size": len(lib) for t, lib in model.plan_libraries.items()})
        models_dir = cfg.output_dir / "models"
        models_dir.mkdir(parents=True, exist_ok=True)
        rn_path = save_rn(model, rn_cfg, FEATURE_LAYOUT, models_dir / f"rn-seed{cfg.seed}.pt")
        mlflow.log_artifact(str(rn_path))
        # traced on up to 8 training rows (a batch of 1 would fix the batch size), checked on the held-out ones
        mlflow.log_metric("registered_reload_max_abs_diff", log_registered_rn(model, x[train][:8], x[val]))
    return TrainedRN(rn_path, features.pointnet_path, acc)


def figure_groups(tasks: list[str], families: list[int]) -> dict[str, np.ndarray]:
    """The rows of Fig 7 and their episodes (indices, ascending): one row per task in order of appearance, and a
    mixed variant's families apart (``"<task> family <k>"``, family >= 0) under its own row of all its scenes."""
    if len(tasks) != len(families):
        raise ValueError(f"{len(tasks)} tasks but {len(families)} families")
    task_arr, fam_arr = np.asarray(tasks), np.asarray(families, dtype=np.int64)
    groups: dict[str, np.ndarray] = {}
    for t in dict.fromkeys(tasks):
        rows = np.flatnonzero(task_arr == t)
        groups[t] = rows
        for f in sorted({int(v) for v in fam_arr[rows] if v >= 0}):
            groups[f"{t} family {f}"] = rows[fam_arr[rows] == f]
    return groups


def demo_counts(groups: dict[str, np.ndarray], weights: np.ndarray) -> dict[str, tuple[int, float]]:
    """Each Fig 7 group's number of demos and the effective sample size of their weights (prior / proposal,
    ``prl.stats.effective_sample_size``): how much the RN has to learn a task, or a mixed variant's family, from."""
    return {name: (len(rows), effective_sample_size(weights[rows])) for name, rows in groups.items()}


def log_registered_rn(model: Any, x_example: np.ndarray, x_check: np.ndarray) -> float:
    """Log the RN as an MLflow model in the ``pt2`` format (no pickle: ``prl.tracking.log_exported_model``),
    traced on ``x_example``, register it as ``prl-rn``, reload it without unpickling and return the largest
    absolute logit difference between the reloaded and the in-memory model on ``x_check``."""
    import torch  # heavy: torch

    model.eval()
    with torch.no_grad():
        logits = model(torch.as_tensor(x_check, dtype=torch.float32)).numpy()
    info = tracking.log_exported_model(model, "rn", x_example, "prl-rn")
    reloaded = tracking.load_exported_model(info.model_uri)
    with torch.no_grad():
        again = reloaded(torch.as_tensor(x_check, dtype=torch.float32)).numpy()
    return float(np.max(np.abs(again - logits)))
