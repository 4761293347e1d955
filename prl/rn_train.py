"""Training of the Representation Network (``prl.rn``) with the Eq 3 loss (``prl.rn.rn_loss``).

Optimiser (the paper is silent): Adam, learning rate 1e-3, no weight decay; 200 epochs of
shuffled minibatches of 64 (``prl.rn.RNConfig``). Inputs are standardised with the training set's
mean/std (:func:`feature_stats`), stored as buffers in the model, so every prediction takes raw ``x``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch import Tensor
from torch.nn import functional as F

from prl.rn import RepresentationNetwork, RNConfig, as_features, as_labels, eval_logits, rn_loss, split_logits

#: Loss terms logged per epoch, as history key suffix -> rn_loss key.
_LOSS_KEYS: dict[str, str] = {
    "loss_ce": "ce", "loss_conf": "confidence", "loss_count": "count", "loss_total": "total",
    "n_confident": "n_confident", "count_on": "count_on",
}


def feature_stats(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-feature mean and (population) std of (N, D) features, in float64."""
    arr = np.asarray(x, dtype=np.float64)
    return arr.mean(axis=0), arr.std(axis=0)


def batch_indices(n: int, batch_size: int, rng: np.random.Generator) -> list[np.ndarray]:
    """One epoch's shuffled minibatches of sample indices.

    ``n > batch_size``: ``n // batch_size`` full batches, the remainder is dropped (drop_last;
    it changes every epoch because the order is reshuffled). ``2 <= n <= batch_size``: one batch
    of all n samples. ``n < 2``: ValueError (BatchNorm1d cannot train on a single sample)."""
    if n < 2:
        raise ValueError(f"RN training needs at least 2 samples (BatchNorm1d), got {n}")
    perm = rng.permutation(n)
    if n <= batch_size:
        return [perm]
    k = n // batch_size
    return list(perm[: k * batch_size].reshape(k, batch_size))



def _accuracy(model: RepresentationNetwork, x: Tensor, y: Tensor) -> np.ndarray:
    parts = split_logits(eval_logits(model, x), model.dims)
    return np.array([float((p.argmax(dim=-1) == y[:, i]).float().mean()) for i, p in enumerate(parts)])


def train_rn(
    x_train: Any,
    y_train: Any,
    cfg: RNConfig | None = None,
    x_val: Any = None,
    y_val: Any = None,
    on_epoch: Callable[[int, dict[str, float]], None] | None = None,
    progress: bool = True,
    w_train: Any = None,
) -> tuple[RepresentationNetwork, list[dict[str, float]]]:
    """Train a :class:`RepresentationNetwork` with the Eq 3 loss; return ``(model in eval mode, history)``.

    ``x_*``: (N, D) raw features (any D); ``y_*``: (N, n) integer labels with n = ``len(cfg.dims)``.
    Features are standardised with the training set's mean/std (stored in the model). Batches follow
    :func:`batch_indices`. ``history[e]`` is a flat dict of epoch e's metrics, keys namespaced
    ``rn/...``: the training loss terms averaged over the epoch's batches (``rn/loss_ce``,
    ``rn/loss_conf``, ``rn/loss_count``, ``rn/loss_total``, ``rn/n_confident``, ``rn/count_on`` = share
    of batches where the indicator fired), per-dimension accuracy in eval mode after the epoch on the
    training set (``rn/train_acc_a{i}``, ``rn/train_acc_mean``) and, with a validation set, on it
    (``rn/val_acc_a{i}``, ``rn/val_acc_mean``, ``rn/val_loss_ce``), and ``rn/epoch_s``. ``on_epoch(e,
    record)`` is called after each epoch (e.g. to log to MLflow). The result depends only on the data
    and ``cfg`` (the seed fixes init, dropout and batch order; the global torch RNG is left untouched)
    for a given torch thread count. ``w_train`` (N,): per-sample weights of the cross-entropy (``prl.rn.rn_loss``;
    the demos' importance weights), None: all 1."""
    cfg = RNConfig() if cfg is None else cfg
    x = as_features(x_train, "x_train")
    y = as_labels(y_train, cfg.dims, "y_train")
    if len(x) != len(y):
        raise ValueError(f"x_train has {len(x)} samples but y_train has {len(y)}")
    if len(x) < 2:
        raise ValueError(f"RN training needs at least 2 samples (BatchNorm1d), got {len(x)}")
    if (x_val is None) != (y_val is None):
        raise ValueError("give both x_val and y_val, or neither")
    xv_t = yv_t = None
    if x_val is not None:
        xv = as_features(x_val, "x_val", x.shape[1])
        yv = as_labels(y_val, cfg.dims, "y_val")
        if len(xv) != len(yv):
            raise ValueError(f"x_val has {len(xv)} samples but y_val has {len(yv)}")
        xv_t, yv_t = torch.from_numpy(xv), torch.from_numpy(yv)
    x_t, y_t = torch.from_numpy(x), torch.from_numpy(y)
    w_t = None
    if w_train is not None:
        w = np.asarray(w_train, dtype=np.float32)
        if w.shape != (len(x),) or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError(f"w_train must be {len(x)} finite weights >= 0, got shape {w.shape}")
        w_t = torch.from_numpy(w)
    mean, std = feature_stats(x)
    rng = np.random.default_rng(cfg.seed)
    history: list[dict[str, float]] = []

    from tqdm.auto import tqdm  # optional display, loaded only when training

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.seed)
        model = RepresentationNetwork(x.shape[1], cfg.dims)
        model.config = cfg
        model.set_standardisation(mean, std)
        opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        bar = tqdm(range(cfg.epochs), desc="RN", unit="epoch", disable=not progress)
        for epoch in bar:
            t0 = time.perf_counter()
            model.train()
            sums = dict.fromkeys(_LOSS_KEYS, 0.0)
            batches = batch_indices(len(x), cfg.batch_size, rng)
            for idx in batches:
                index = torch.from_numpy(idx)
                parts = split_logits(model(x_t[index]), cfg.dims)
                terms = rn_loss(parts, y_t[index], cfg, None if w_t is None else w_t[index])
                opt.zero_grad(set_to_none=True)
                terms["total"].backward()
                opt.step()
                for key, term in _LOSS_KEYS.items():
                    sums[key] += float(terms[term].detach())
            record = {f"rn/{key}": value / len(batches) for key, value in sums.items()}
            acc = _accuracy(model, x_t, y_t)
            record |= {f"rn/train_acc_a{i}": float(a) for i, a in enumerate(acc)}
            record["rn/train_acc_mean"] = float(acc.mean())
            if xv_t is not None and yv_t is not None:
                logits = eval_logits(model, xv_t)
                parts = split_logits(logits, cfg.dims)
                vacc = [float((p.argmax(-1) == yv_t[:, i]).float().mean()) for i, p in enumerate(parts)]
                record |= {f"rn/val_acc_a{i}": a for i, a in enumerate(vacc)}
                record["rn/val_acc_mean"] = float(np.mean(vacc))
                record["rn/val_loss_ce"] = float(sum(F.cross_entropy(p, yv_t[:, i]) for i, p in enumerate(parts)))
            record["rn/epoch_s"] = time.perf_counter() - t0
            history.append(record)
            bar.set_postfix(loss=f"{record['rn/loss_total']:.3f}", acc=f"{record['rn/train_acc_mean']:.3f}")
            if on_epoch is not None:
                on_epoch(epoch, record)
    model.eval()
    return model, history
