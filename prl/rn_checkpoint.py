"""Representation Network checkpoints: one torch file per trained RN (``prl.rn.RepresentationNetwork``).

A checkpoint holds the weights (with the input standardisation), the ``RNConfig``, the input
``FeatureLayout``, the per-task plan libraries and priors of library decoding (``prl.rn_decode``)
and the SHA-256 of the PointNet the inputs were encoded with. It is written atomically
(``prl.atomic``) and read with ``weights_only=True``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from prl.atomic import atomic_file
from prl.rn import FeatureLayout, RepresentationNetwork, RNConfig
from prl.rn_decode import check_library, check_prior

#: Checkpoint format tag written by :func:`save_rn`.
CHECKPOINT_FORMAT = "prl-rn/1"


def save_rn(model: RepresentationNetwork, cfg: RNConfig, layout: FeatureLayout, path: str | Path) -> Path:
    """Write the model, its config, its input layout, its ``plan_libraries``, ``plan_priors`` and
    ``pointnet_sha256`` to ``path`` (torch file, atomically); return the path."""
    if layout.dim != model.in_dim:
        raise ValueError(f"layout length {layout.dim} ({layout.describe()}) does not match the model's "
                         f"input length {model.in_dim}")
    if tuple(cfg.dims) != model.dims:
        raise ValueError(f"cfg.dims {cfg.dims} does not match the model's dims {model.dims}")
    libraries = {str(task): check_library(lib, model.dims, f"plan library of task {task!r}").tolist()
                 for task, lib in model.plan_libraries.items()}
    priors = {str(task): [q.tolist() for q in check_prior(prior, model.dims, f"plan prior of task {task!r}")]
              for task, prior in model.plan_priors.items()}
    path = Path(path)
    cfg_dict = asdict(cfg) | {"dims": list(cfg.dims)}
    payload = {"format": CHECKPOINT_FORMAT, "in_dim": model.in_dim, "dims": list(model.dims),
               "config": cfg_dict, "layout": layout.to_json(), "plan_libraries": libraries, "plan_priors": priors,
               "pointnet_sha256": model.pointnet_sha256,
               "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()}}
    with atomic_file(path, "wb") as fh:
        torch.save(payload, fh)
    return path


def read_checkpoint(path: Path, fmt: str, kind: str) -> dict[str, Any]:
    """The payload of a torch checkpoint written with format tag ``fmt`` (read with ``weights_only=True``);
    FileNotFoundError names a missing path, ValueError a file that is not a readable ``kind`` checkpoint of that
    format."""
    if not path.is_file():
        raise FileNotFoundError(f"{kind} checkpoint not found: {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many kinds for a bad file
        raise ValueError(f"{path} is not a readable {kind} checkpoint: {exc}") from exc
    if not isinstance(payload, dict) or payload.get("format") != fmt:
        got = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise ValueError(f"{path} is not a {kind} checkpoint of format {fmt!r} (got {got!r})")
    return payload


def load_rn(path: str | Path, expected_layout: FeatureLayout | None = None) -> RepresentationNetwork:
    """Read a :func:`save_rn` checkpoint: the model in eval mode, with ``model.config`` and ``model.layout``.

    FileNotFoundError names a missing path; ValueError names both layouts when ``expected_layout``
    differs from the stored one, or says what is wrong with a file that is not an RN checkpoint."""
    path = Path(path)
    payload = read_checkpoint(path, CHECKPOINT_FORMAT, "RN")
    layout = FeatureLayout.from_json(payload["layout"])
    if expected_layout is not None and layout != expected_layout:
        raise ValueError(f"{path} was trained on feature layout [{layout.describe()}], but the caller expects "
                         f"[{expected_layout.describe()}]")
    cfg_raw: Mapping[str, Any] = payload["config"]
    cfg = RNConfig(**{**cfg_raw, "dims": tuple(cfg_raw["dims"])})
    model = RepresentationNetwork(int(payload["in_dim"]), tuple(payload["dims"]))
    model.load_state_dict(payload["state_dict"])
    model.config, model.layout = cfg, layout
    model.plan_libraries = {t: np.asarray(lib, dtype=np.int64)
                            for t, lib in (payload.get("plan_libraries") or {}).items()}
    model.plan_priors = {t: tuple(np.asarray(q, dtype=float) for q in prior)
                         for t, prior in (payload.get("plan_priors") or {}).items()}
    model.pointnet_sha256 = payload.get("pointnet_sha256")
    model.eval()
    return model
