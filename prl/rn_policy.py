"""The RN as a policy: its per-dimension distributions decoded into one plan for a live scene.

Used by the pipeline's ``rn-eval`` stage and ``flows.evaluate_rn``; the LN's policy is ``prl.ln.ln_policy``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from prl.plb import load_plb
from prl.version import file_digest

#: How the RN's per-dimension distributions become one plan (each evaluated in simulation): 'rn' the
#: per-dimension argmax (the paper), 'rn_library' the most probable plan among the task's demonstrated
#: plans, 'rn_success' the same divided by the sampling prior (ranks by success probability); see
#: ``prl.rn_decode.library_plan``.
DECODINGS: tuple[str, ...] = ("rn", "rn_library", "rn_success")


def decoding(model: Any, task_name: str, kind: str) -> tuple[np.ndarray | None, tuple[np.ndarray, ...] | None]:
    """(library, prior) of ``predict_plan`` for a decoding of ``DECODINGS``; a clear error for an unknown one or
    a model without a plan library for the task.

    'rn_success' divides by the prior stored with the model (``model.plan_priors``); a checkpoint written
    before priors were stored falls back to the task's prior in the current PLB catalogue."""
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
    from prl.features import scene_features  # heavy: trimesh
    from prl.rn_decode import predict_plan

    library, prior = decoding(model, task_name, kind)

    def choose(i: int, env: Any, x_manip: np.ndarray) -> list[int]:
        x = scene_features(task_name, int(seeds[i]), dict(env.scene_params), x_manip, texts[i % len(texts)],
                           pointnet, n_points)
        return predict_plan(model, x, library, prior)[0].tolist()

    return choose
