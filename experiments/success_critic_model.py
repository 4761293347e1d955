"""A success critic: P(success | x, plan), learnt from every synthesis attempt, to rank the RN's plans (issue #26).
An experiment (``python -m experiments.success_critic``), not a pipeline stage; not to be confused with A2C's value
critic (``prl.ln``).

Why. The RN learns p(plan | x, success) with the plans drawn from the task's prior (Eq 3 on the demos, weighted by
prior / proposal): by Bayes that is ``prior(plan) * P(success | plan, x)`` up to a constant, so its mode is the plan
most often *kept*, not the one most likely to succeed. On the mixed variants the two differ
(``docs/guide/tasks.md``, mixed variants: the wide lids' most frequent successful plan opens about half of them, the
hand-written one nearly all), and more demos sharpen that mode instead of moving it. Dividing the RN's per-dimension
heads by the prior (decoding ``rn_success``) is the same idea on a factorised model, which the ratio amplifies the
errors of.
The attempt log holds what the demos leave out, the failures: a classifier of the outcome of (x, plan) trained on
all attempts estimates ``P(success | x, plan)`` directly. The adaptive proposal's plans do not bias it (it
conditions on the plan; the proposal only decides where it sees many examples).

Decoding (``critic_plan``): among the plans of a library (the RN's: the task's distinct demonstrated plans), take
the RN's ``top_k`` by its joint score (``prl.rn_decode.library_plan``'s), then the one the critic gives the highest
success probability. ``top_k`` = the library's size ranks the whole library by the critic alone; ``top_k`` = 1 is
the ``rn_library`` decoding. Keeping to the RN's candidates keeps the critic where it has seen the plan played on
scenes like this one.

The network: x (standardised with the training set's mean and std, stored as buffers) through two layers to 64
values, joined with the plan's one-hot choices, then two layers to one logit. Adam, binary cross-entropy, the
validation split held out by scene seed; the weights of the epoch with the lowest validation loss are kept.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn
from torch.nn import functional as F

from prl.atomic import atomic_file
from prl.constants import RS_DIMS
from prl.rn import STD_FLOOR, as_features, as_labels, is_int, is_number
from prl.rn_checkpoint import read_checkpoint
from prl.rn_decode import check_library, library_scores
from prl.rn_train import feature_stats

#: Checkpoint format tag written by :func:`save_critic`.
CHECKPOINT_FORMAT = "prl-critic/1"


@dataclass(frozen=True)
class CriticConfig:
    """Hyper-parameters of the success critic."""

    hidden: int = 256
    """Width of the first layer over x (the second is 64; the head over [x code | plan] is ``hidden // 2``)."""
    dropout: float = 0.3
    """Dropout after each hidden layer."""
    epochs: int = 30
    """Passes over the training attempts (hammer_mixed's 6,223 attempts: held-out loss lowest at about 15)."""
    batch_size: int = 128
    """Minibatch size."""
    lr: float = 1e-3
    """Adam learning rate."""
    weight_decay: float = 1e-4
    """Adam (L2) weight decay."""
    seed: int = 0
    """Seed of the weight init, dropout masks and batch order."""
    dims: tuple[int, ...] = RS_DIMS
    """Number of choices of each plan dimension."""

    def __post_init__(self) -> None:
        for name in ("hidden", "epochs", "batch_size"):
            if not is_int(getattr(self, name)) or getattr(self, name) < 2:
                raise ValueError(f"{name} must be an integer >= 2, got {getattr(self, name)!r}")
        if not is_int(self.seed) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")
        if not is_number(self.dropout) or not 0 <= self.dropout < 1:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout!r}")
        for name in ("lr", "weight_decay"):
            value = getattr(self, name)
            if not is_number(value) or not math.isfinite(value) or value < 0 or (name == "lr" and value == 0):
                raise ValueError(f"{name} must be a finite number {'> 0' if name == 'lr' else '>= 0'}, got {value!r}")
        dims = tuple(self.dims)
        if not dims or not all(is_int(m) and m >= 2 for m in dims):
            raise ValueError(f"dims must be a non-empty sequence of integers >= 2, got {self.dims!r}")
        object.__setattr__(self, "dims", tuple(int(m) for m in dims))


class PlanCritic(nn.Module):
    """Logit of P(success | x, plan) for raw features x (N, in_dim) and plans (N, n) of choices within ``dims``."""

    def __init__(self, in_dim: int, dims: Sequence[int], hidden: int = 256, dropout: float = 0.3) -> None:
        super().__init__()
        self.in_dim, self.dims = int(in_dim), tuple(int(m) for m in dims)
        self.register_buffer("mean", torch.zeros(self.in_dim))
        self.register_buffer("scale", torch.ones(self.in_dim))
        self.encode = nn.Sequential(nn.Linear(self.in_dim, hidden), nn.ReLU(), nn.Dropout(dropout),
                                    nn.Linear(hidden, 64), nn.ReLU())
        self.head = nn.Sequential(nn.Linear(64 + sum(self.dims), hidden // 2), nn.ReLU(), nn.Dropout(dropout),
                                  nn.Linear(hidden // 2, 1))

    def set_standardisation(self, mean: np.ndarray, std: np.ndarray) -> None:
        """Centre by ``mean``; scale by ``std`` where it is not below ``prl.rn.STD_FLOOR`` (the RN's rule)."""
        self.mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        self.scale.copy_(torch.as_tensor(np.where(np.asarray(std) < STD_FLOOR, 1.0, std), dtype=torch.float32))

    def forward(self, x: Tensor, plan: Tensor) -> Tensor:
        onehot = torch.cat([F.one_hot(plan[:, i], m) for i, m in enumerate(self.dims)], dim=1).float()
        code = self.encode((x - self.mean) / self.scale)
        return self.head(torch.cat([code, onehot], dim=1)).squeeze(1)


def _check_attempts(x: Any, plans: Any, success: Any, dims: Sequence[int], what: str) -> tuple[Tensor, Tensor, Tensor]:
    """Tensors of one set of attempts; ValueError naming the set and what is wrong."""
    xa = as_features(x, f"{what} x")
    pa = as_labels(plans, tuple(dims), f"{what} plans")
    sa = np.asarray(success)
    if sa.shape != (len(xa),) or len(pa) != len(xa):
        raise ValueError(f"{what}: x has {len(xa)} rows, plans {len(pa)}, success shape {sa.shape}; they must agree")
    if not np.isin(sa, (0, 1)).all():
        raise ValueError(f"{what} success must be 0/1 or booleans")
    return torch.from_numpy(xa), torch.from_numpy(pa), torch.from_numpy(sa.astype(np.float32))


def train_critic(x: Any, plans: Any, success: Any, cfg: CriticConfig | None = None, x_val: Any = None,
                 plans_val: Any = None, success_val: Any = None,
                 progress: bool = True) -> tuple[PlanCritic, list[dict[str, float]]]:
    """Train a :class:`PlanCritic` on attempts (x (N, D), plans (N, n), success (N,)); return (model in eval mode,
    history). With a validation set the weights of the epoch with the lowest validation loss are kept; each
    history row has ``critic/train_loss`` and, with a validation set, ``critic/val_loss``, ``critic/val_auc`` and
    ``critic/base_loss`` (the loss of predicting the training success rate everywhere: what x and the plan add)."""
    cfg = CriticConfig() if cfg is None else cfg
    xt, pt, st = _check_attempts(x, plans, success, cfg.dims, "training")
    if len(xt) < 2 or st.min() == st.max():
        raise ValueError(f"the critic needs successes and failures to learn from; got {int(st.sum())} of {len(st)}")
    val = None if x_val is None else _check_attempts(x_val, plans_val, success_val, cfg.dims, "validation")
    rate = float(st.mean())
    from tqdm.auto import tqdm  # optional display, loaded only when training

    history: list[dict[str, float]] = []
    rng = np.random.default_rng(cfg.seed)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.seed)
        model = PlanCritic(xt.shape[1], cfg.dims, cfg.hidden, cfg.dropout)
        model.set_standardisation(*feature_stats(xt.numpy()))
        opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        best, best_state = math.inf, None
        for _ in tqdm(range(cfg.epochs), desc="critic", unit="epoch", disable=not progress):
            model.train()
            total = 0.0
            perm = torch.from_numpy(rng.permutation(len(xt)))
            for idx in perm.split(cfg.batch_size):
                loss = F.binary_cross_entropy_with_logits(model(xt[idx], pt[idx]), st[idx])
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                total += float(loss.detach()) * len(idx)
            row = {"critic/train_loss": total / len(xt)}
            if val is not None:
                logits = critic_logits(model, val[0], val[1])
                row |= {"critic/val_loss": float(F.binary_cross_entropy_with_logits(logits, val[2])),
                        "critic/val_auc": auc(val[2].numpy(), logits.numpy()),
                        "critic/base_loss": float(F.binary_cross_entropy(torch.full_like(val[2], rate), val[2]))}
                if row["critic/val_loss"] < best:
                    best, best_state = row["critic/val_loss"], {k: v.clone() for k, v in model.state_dict().items()}
            history.append(row)
        if best_state is not None:
            model.load_state_dict(best_state)
    model.config = cfg
    model.eval()
    return model, history


def critic_logits(model: PlanCritic, x: Any, plans: Any) -> Tensor:
    """(N,) logits of raw x (N, D) with plans (N, n), in eval mode, without gradients."""
    xt = torch.as_tensor(np.asarray(x, dtype=np.float32)) if not isinstance(x, Tensor) else x
    pt = torch.as_tensor(np.asarray(plans, dtype=np.int64)) if not isinstance(plans, Tensor) else plans
    was = model.training
    model.eval()
    with torch.no_grad():
        out = model(xt, pt)
    model.train(was)
    return out


def auc(labels: np.ndarray, scores: np.ndarray) -> float:
    """Area under the ROC curve: the chance that a random positive scores above a random negative (ties count
    half); NaN without both classes."""
    y = np.asarray(labels).astype(bool)
    s = np.asarray(scores, dtype=np.float64)
    pos, neg = s[y], s[~y]
    if not len(pos) or not len(neg):
        return float("nan")
    order = np.sort(neg)
    below = np.searchsorted(order, pos, side="left")
    ties = np.searchsorted(order, pos, side="right") - below
    return float((below + 0.5 * ties).sum() / (len(pos) * len(neg)))


def critic_plan(model: PlanCritic, x: Any, library: Any, rn_probs: Sequence[np.ndarray] | None = None,
                top_k: int | None = None) -> np.ndarray:
    """(N, n) plans: per sample of x (N, D), the library plan with the highest critic success probability among
    the RN's ``top_k`` library plans (by ``sum_i log p_i(choice_i)`` of ``rn_probs``, the RN's per-dimension (N, m_i)
    probabilities); without ``rn_probs`` (or ``top_k`` None) among the whole library. Ties: the RN's better-ranked,
    then the earlier library row."""
    lib = check_library(library, model.dims)
    xa = np.atleast_2d(np.asarray(x, dtype=np.float32))
    n, k = len(xa), len(lib)
    if rn_probs is None or top_k is None:
        order = np.tile(np.arange(k), (n, 1))
    else:
        if not is_int(top_k) or top_k < 1:
            raise ValueError(f"top_k must be an integer >= 1, got {top_k!r}")
        order = np.argsort(-library_scores(rn_probs, lib), axis=1, kind="stable")[:, :min(top_k, k)]
    cand = lib[order]  # (N, c, n)
    c = cand.shape[1]
    logits = critic_logits(model, np.repeat(xa, c, axis=0), cand.reshape(n * c, -1)).numpy().reshape(n, c)
    return cand[np.arange(n), np.argmax(logits, axis=1)]


def save_critic(model: PlanCritic, path: str | Path, meta: dict[str, Any] | None = None) -> Path:
    """Write the critic (weights, config, ``meta``, e.g. the task and the PointNet's digest) atomically."""
    path = Path(path)
    payload = {"format": CHECKPOINT_FORMAT, "in_dim": model.in_dim, "config": asdict(model.config) | {
        "dims": list(model.config.dims)}, "meta": dict(meta or {}),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()}}
    with atomic_file(path, "wb") as fh:
        torch.save(payload, fh)
    return path


def load_critic(path: str | Path) -> PlanCritic:
    """Read a :func:`save_critic` file (model in eval mode, ``model.config``, ``model.meta``); FileNotFoundError
    names a missing path, ValueError a file of another kind."""
    payload = read_checkpoint(Path(path), CHECKPOINT_FORMAT, "critic")
    raw = payload["config"]
    cfg = CriticConfig(**{**raw, "dims": tuple(raw["dims"])})
    model = PlanCritic(int(payload["in_dim"]), cfg.dims, cfg.hidden, cfg.dropout)
    model.load_state_dict(payload["state_dict"])
    model.config, model.meta = cfg, dict(payload.get("meta") or {})
    model.eval()
    return model
