"""From the Representation Network's heads (``prl.rn``) to plans, and what the heads agree on (paper Fig 7).

Decoding: the paper takes each dimension's most probable choice (:func:`predict_plan`); with a plan
library it takes the best demonstrated plan instead (:func:`library_plan`, optionally corrected by
the prior the demos' plans were sampled with).

Key dimensions (paper Fig 7, "a high concentration of probabilities indicates key categories"):
over a set of samples (one task), dimension i is *key* when the mean predicted distribution is
concentrated: its largest mean probability exceeds ``tau/m_i`` (``tau = tau_s = 2`` by
default), i.e. the network predicts the same choice, confidently, across the task's samples.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from prl.rn import RepresentationNetwork, as_features, as_labels, eval_logits, is_number, split_logits


def predict_proba(model: RepresentationNetwork, x: Any) -> list[np.ndarray]:
    """Per dimension, the (N, m_i) predicted probabilities for raw features x (N, in_dim) (eval mode)."""
    arr = as_features(np.asarray(x)[None, :] if np.ndim(x) == 1 else x, "x", model.in_dim)
    parts = split_logits(eval_logits(model, torch.from_numpy(arr)), model.dims)
    return [torch.softmax(p, dim=-1).numpy() for p in parts]


def library_plan(probs: Sequence[np.ndarray], library: Any, prior: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """Joint decoding over a plan library: for each of N samples, the library plan with the largest
    ``sum_i log p_i(choice_i)`` (minus ``sum_i log prior_i(choice_i)`` when ``prior`` is given);
    returns (N, n) int64 (ties: the earlier library row).

    ``probs`` are :func:`predict_proba`'s per-dimension (N, m_i) probabilities; ``library`` is a (K, n)
    array of plan vectors, e.g. the distinct plans the training demos executed successfully. The RN's
    heads are independent, so the per-dimension argmax is the joint argmax over *all* plans; it can
    combine choices that were never demonstrated together. Restricting the argmax to the library
    keeps the RN's ranking but only among combinations physics has confirmed somewhere.

    ``prior`` (per dimension, the (m_i,) probabilities the demos' plans were sampled with): the RN
    learns p(plan | scene, success), which by Bayes is proportional to prior(plan) * P(success | plan,
    scene). Dividing by the prior ranks plans by their success probability instead of by how often
    the sampler tried them."""
    lib = check_library(library, [p.shape[1] for p in probs])
    return lib[np.argmax(library_scores(probs, lib, prior), axis=1)]


def library_scores(probs: Sequence[np.ndarray], lib: np.ndarray, prior: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """(N, K) joint log-scores ``sum_i log p_i(choice_i)`` of the K rows of a checked library ``lib`` (minus the
    prior's, when given) for :func:`library_plan` and the success critic's candidates
    (``experiments.success_critic_model.critic_plan``)."""
    dims = [p.shape[1] for p in probs]
    # the floor keeps log finite where a probability underflows to 0
    score = sum(np.log(np.maximum(p, 1e-30))[:, lib[:, i]] for i, p in enumerate(probs))
    if prior is not None:
        score = score - sum(np.log(q)[lib[:, i]] for i, q in enumerate(check_prior(prior, dims)))
    return score


def check_prior(prior: Any, dims: Sequence[int], what: str = "prior") -> tuple[np.ndarray, ...]:
    """``prior`` as one float (m_i,) array per dimension of ``dims``, each of positive probabilities summing
    to 1; else ValueError naming the sizes, or the dimension and its bad values (``what`` starts it)."""
    sizes = [np.shape(q) for q in prior] if isinstance(prior, Sequence) else np.shape(prior)
    if not isinstance(prior, Sequence) or len(prior) != len(dims) or any(
            np.shape(q) != (m,) for q, m in zip(prior, dims)):
        raise ValueError(f"{what} must give {len(dims)} dimensions of positive probabilities of sizes "
                         f"{list(dims)}, got sizes {sizes}")
    out = tuple(np.asarray(q, dtype=float) for q in prior)
    for i, q in enumerate(out):
        if not np.all(q > 0) or abs(q.sum() - 1.0) > 1e-6:
            raise ValueError(f"{what} dimension {i} must be positive probabilities summing to 1, got {q.tolist()}")
    return out


def check_library(library: Any, dims: Sequence[int], what: str = "plan library") -> np.ndarray:
    """``library`` as a (K >= 1, len(dims)) int64 array of choices within ``dims``; else ValueError naming the
    shape, dtype, or the first row with an out-of-range choice (``what`` starts the message)."""
    lib = np.asarray(library)
    n = len(dims)
    if lib.ndim != 2 or lib.shape[0] < 1 or lib.shape[1] != n:
        raise ValueError(f"{what} must have shape (K >= 1, {n}), got {lib.shape}")
    if not np.issubdtype(lib.dtype, np.integer):
        raise ValueError(f"{what} must hold integer choices, got dtype {lib.dtype}")
    for i, m in enumerate(dims):
        bad = (lib[:, i] < 0) | (lib[:, i] >= m)
        if bad.any():
            raise ValueError(f"{what} row {int(np.argmax(bad))} has choice {int(lib[bad, i][0])} for "
                             f"dimension {i}, which has {m} choices")
    return lib.astype(np.int64)


def predict_plan(model: RepresentationNetwork, x: Any, library: Any = None,
                 prior: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """The (N, n) int64 plan vectors: per dimension the most probable choice (the paper's decoding),
    or with ``library`` the best plan among the library's rows (:func:`library_plan`, with ``prior``)."""
    probs = predict_proba(model, x)
    if library is not None:
        return library_plan(probs, library, prior)
    if prior is not None:
        raise ValueError("prior correction needs a plan library (pass library=...)")
    return np.stack([p.argmax(axis=-1) for p in probs], axis=1).astype(np.int64)


def plan_library(plans: Any) -> np.ndarray:
    """The distinct rows of (N, n) plan vectors, sorted (a deterministic library for :func:`library_plan`)."""
    arr = np.asarray(plans, dtype=np.int64)
    if arr.ndim != 2 or arr.shape[0] < 1:
        raise ValueError(f"plans must have shape (N >= 1, n), got {arr.shape}")
    return np.unique(arr, axis=0)


def plan_libraries(plans: Any, tasks: Sequence[str]) -> dict[str, np.ndarray]:
    """Per task, :func:`plan_library` of that task's rows of ``plans``."""
    arr = np.asarray(plans)
    names = np.asarray(list(tasks))
    if len(names) != len(arr):
        raise ValueError(f"plans and tasks differ in length: {len(arr)} != {len(names)}")
    return {str(t): plan_library(arr[names == t]) for t in sorted(set(names.tolist()))}


def per_dim_accuracy(model: RepresentationNetwork, x: Any, y: Any) -> np.ndarray:
    """(n,) share of samples whose predicted choice equals the label, per dimension."""
    labels = as_labels(y, model.dims, "y")
    plans = predict_plan(model, x)
    if len(plans) != len(labels):
        raise ValueError(f"x has {len(plans)} samples but y has {len(labels)}")
    return (plans == labels).mean(axis=0)


@dataclass(frozen=True)
class DimensionSummary:
    """How concentrated the RN's predictions of one dimension are over a set of samples (Fig 7)."""

    index: int
    """Dimension index i."""
    mean_probs: np.ndarray
    """(m_i,) mean predicted probability of each choice over the samples (the bars of Fig 7)."""
    mean_max_prob: float
    """Mean over samples of the per-sample largest probability (confidence, whatever the choice)."""
    top_choice: int
    """Choice with the largest mean probability."""
    top_prob: float
    """That largest mean probability."""
    threshold: float
    """``tau / m_i``."""
    key: bool
    """``top_prob > threshold``: the samples agree, confidently, on ``top_choice``."""


def key_dimensions(probs: Sequence[np.ndarray], tau: float = 2.0,
                   weights: Sequence[float] | None = None) -> list[DimensionSummary]:
    """Summarise per-dimension probabilities ``probs[i]`` (N, m_i) of one task (see the module docstring).

    A dimension is key when the largest entry of its mean probability vector exceeds ``tau / m_i``
    (default ``tau`` = the paper's ``tau_s`` = 2: twice the uniform probability). The mean over
    samples is used, not each sample's maximum, so that confident but disagreeing predictions (no
    shared rule) do not count. ``weights`` (N,): the samples' weights in the means (the demos' importance
    weights, ``prl.proposal``); None: equal."""
    if not is_number(tau) or not tau > 0:
        raise ValueError(f"tau must be a number > 0, got {tau!r}")
    out = []
    for i, p in enumerate(probs):
        arr = np.asarray(p, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] < 2:
            raise ValueError(f"probs[{i}] must be (samples > 0, choices >= 2), got shape {arr.shape}")
        w = np.ones(len(arr)) if weights is None else np.asarray(weights, dtype=np.float64)
        if w.shape != (len(arr),):
            raise ValueError(f"weights must have one value per sample ({len(arr)}), got shape {w.shape}")
        mean = np.average(arr, axis=0, weights=w)
        top = int(mean.argmax())
        threshold = tau / arr.shape[1]
        out.append(DimensionSummary(index=i, mean_probs=mean, mean_max_prob=float(np.average(arr.max(axis=1), weights=w)),
                                    top_choice=top, top_prob=float(mean[top]), threshold=threshold,
                                    key=bool(mean[top] > threshold)))
    return out

