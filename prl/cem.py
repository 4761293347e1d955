"""The cross-entropy method over plan vectors: one categorical distribution per Representation-Space dimension.

Pure maths (numpy), used by the red-team search (``envs.red_team``). A round samples plans from the
per-dimension categoricals, scores them in simulation, and moves each dimension's distribution towards the
frequencies of its choices among the elite plans:

    p_d <- smoothing * freq_d(elites) + (1 - smoothing) * p_d,   then   p_d <- max(p_d, floor * q_d), renormalised

where ``q_d`` is a reference distribution (the uniform one, or a task's prior): the floor keeps every choice the
reference allows at a fixed fraction of its reference probability, so the search never stops looking anywhere.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def uniform(sizes: Sequence[int]) -> list[np.ndarray]:
    """The uniform categorical of each dimension."""
    return [np.full(int(m), 1.0 / int(m)) for m in sizes]


def sample(probs: Sequence[np.ndarray], n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, len(probs)) int64 plans, each dimension drawn from its categorical."""
    return np.stack([rng.choice(len(p), size=n, p=p) for p in probs], axis=1).astype(np.int64)


def elites(plans: np.ndarray, scores: np.ndarray, fraction: float) -> np.ndarray:
    """The top ``fraction`` of ``plans`` by ``scores`` (at least one; ties keep the earlier plan)."""
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"elite fraction must be in (0, 1], got {fraction!r}")
    if len(plans) != len(scores) or len(plans) == 0:
        raise ValueError(f"need as many scores as plans, and some: {len(plans)} plans, {len(scores)} scores")
    k = max(1, round(fraction * len(plans)))
    order = np.argsort(-np.asarray(scores, dtype=float), kind="stable")
    return np.asarray(plans)[order[:k]]


def update(probs: Sequence[np.ndarray], elite_plans: np.ndarray, smoothing: float = 0.7,
           reference: Sequence[np.ndarray] | None = None, floor: float = 0.0,
           weights: Sequence[float] | None = None) -> list[np.ndarray]:
    """One CEM step (the module docstring): the new categorical of each dimension. ``weights``: one per elite plan
    (the frequencies are then weighted ones; None counts every plan once)."""
    if not 0.0 <= smoothing <= 1.0:
        raise ValueError(f"smoothing must be in [0, 1], got {smoothing!r}")
    if not 0.0 <= floor < 1.0:
        raise ValueError(f"floor must be in [0, 1), got {floor!r}")
    elite_plans = np.asarray(elite_plans, dtype=np.int64).reshape(-1, len(probs))
    w = np.ones(len(elite_plans)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (len(elite_plans),) or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"need one finite weight >= 0 per elite plan: {len(elite_plans)} plans, weights {w!r}")
    reference = reference if reference is not None else uniform([len(p) for p in probs])
    out = []
    for d, p in enumerate(probs):
        freq = np.bincount(elite_plans[:, d], weights=w, minlength=len(p)).astype(float)
        freq = freq / freq.sum() if freq.sum() else np.asarray(p, dtype=float)
        new = smoothing * freq + (1.0 - smoothing) * np.asarray(p, dtype=float)
        new = np.maximum(new, floor * np.asarray(reference[d], dtype=float))
        out.append(new / new.sum())
    return out
