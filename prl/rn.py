"""Representation Network (RN): paper Sec. IV-B, Table I and the loss of Eq 3.

The RN is a multi-head classifier: one input vector ``x`` (any length; in this project
``[x_manip 784 | TE 384 | PN tool 256 | PN object 256]`` = 1680, ``prl.features.FEATURE_LAYOUT``)
gives one categorical distribution per Representation Space dimension (``RS_DIMS``, sizes m_i).
The network is exactly Table I; its ``sum(m_i)`` logits are split per dimension.

Reading of Eq 3 (the paper leaves the reductions open; these are the choices made here and the
tests pin them down)::

    L = CE + lambda * H + gamma * 1{ C < T_min }

* ``CE`` = the cross-entropy **summed over the batch** and over the n dimensions
  (``-sum_b sum_i sum_k y_bik log y^_bik``). Eq 3 writes its first term as a sum over samples.
* ``H`` = sum over dimensions of the **batch mean** of the hinge ``max(0, tau_c/m_i - p_i^max)``,
  where ``p_i^max`` is the largest softmax probability of dimension i. Eq 3 writes no batch sum
  for this term; it is a property of the batch's predictions. With CE summed and H averaged,
  ``lambda = 1 x bs`` (the paper's value) gives both terms the same per-sample weight: that the
  paper scales lambda with the batch size is what suggests this reading. (An earlier reading
  here, with CE averaged too, made the hinge 64 times CE, and training locked each head onto
  a confident but arbitrary choice: 35% mean validation accuracy after 20 epochs on the tests'
  synthetic problem.) The hinge pushes each head towards a peaked distribution, whatever the class.
* ``C`` = the number of confident predictions **in the batch, counted over (sample, dimension)
  pairs**: pairs with ``p_i^max > tau_s/m_i`` (strict). The text says the penalty applies when
  confident predictions are fewer than T_min "within a batch". A per-sample count cannot reach
  the paper's ``T_min = bs/10 = 6.4`` with only 6 dimensions, so the penalty would always fire;
  counting over the batch's pairs (at most ``bs * n``) is the only reading in which the
  paper's values make the indicator a real test.
* The indicator term is a step function of the network outputs: it has **no gradient**. It is
  computed under ``no_grad``, logged, and added to ``total`` as a constant, so it changes the
  reported loss but not the parameter update (tests check that the gradient of ``total`` equals
  that of ``ce + confidence``).
* ``lambda``, ``gamma`` and ``T_min`` are constants resolved from ``RNConfig.batch_size`` (paper:
  ``1 x bs``, ``0.01 x bs``, ``bs/10``); they are not rescaled for a smaller batch.
* ``tau_c = tau_s = 2`` gives thresholds ``2/m_i`` (2/7 = 0.286, 2/6 = 0.333, 2/4 = 0.5). For a
  dimension with ``m_i <= tau`` the threshold is >= 1: its hinge never reaches zero and its
  predictions never count as confident (not the case for ``RS_DIMS``).

Optimiser (the paper is silent): Adam, learning rate 1e-3, no weight decay; 200 epochs of
shuffled minibatches of 64. Inputs are standardised with the training set's mean/std, stored as
buffers in the model, so every prediction takes raw ``x``.

Key dimensions (paper Fig 7, "a high concentration of probabilities indicates key categories"):
over a set of samples (one task), dimension i is *key* when the mean predicted distribution is
concentrated: its largest mean probability exceeds ``tau/m_i`` (``tau = tau_s = 2`` by
default), i.e. the network predicts the same choice, confidently, across the task's samples.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn
from torch.nn import functional as F

from prl.constants import RS_DIMS

#: Hidden widths of Table I.
HIDDEN: tuple[int, ...] = (512, 256, 128)
#: Dropout probabilities of Table I, one per hidden block.
DROPOUT: tuple[float, ...] = (0.5, 0.5, 0.4)
#: Features whose training-set std is below this are only centred, not scaled.
STD_FLOOR = 1e-6
#: Checkpoint format tag written by :func:`save_rn`.
CHECKPOINT_FORMAT = "prl-rn/1"
#: Rows per forward pass in the prediction helpers.
PREDICT_CHUNK = 4096


def _is_int(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)


# ------------------------------------------------------------------ config


@dataclass(frozen=True)
class RNConfig:
    """Hyper-parameters of RN training (paper Sec. V-B; ``None`` means the paper's rule)."""

    batch_size: int = 64
    """Minibatch size ``bs`` (paper: 64). At least 2 (BatchNorm1d needs 2 samples to train)."""
    lam: float | None = None
    """lambda, weight of the confidence hinge; ``None`` -> ``1 x batch_size`` (paper)."""
    gamma: float | None = None
    """gamma, weight of the count indicator; ``None`` -> ``0.01 x batch_size`` (paper)."""
    tau_c: float = 2.0
    """tau_c: the hinge's threshold on dimension i is ``tau_c / m_i`` (paper: 2)."""
    tau_s: float = 2.0
    """tau_s: a prediction of dimension i is confident when its max prob > ``tau_s / m_i`` (paper: 2)."""
    t_min: float | None = None
    """T_min, fewest confident (sample, dim) pairs per batch before the penalty; ``None`` -> ``bs/10``."""
    epochs: int = 200
    """Passes over the training set (paper: 200)."""
    lr: float = 1e-3
    """Adam learning rate (the paper does not say; 1e-3 is Adam's usual default)."""
    weight_decay: float = 0.0
    """Adam (L2) weight decay."""
    seed: int = 0
    """Seed of the weight init, dropout masks and batch order."""
    dims: tuple[int, ...] = RS_DIMS
    """Number of choices m_i of each Representation Space dimension."""

    def __post_init__(self) -> None:
        if not _is_int(self.batch_size) or self.batch_size < 2:
            raise ValueError(f"batch_size must be an integer >= 2 (BatchNorm1d), got {self.batch_size!r}")
        for name in ("lam", "gamma", "t_min"):
            value = getattr(self, name)
            if value is not None and (not _is_number(value) or not math.isfinite(value) or value < 0):
                raise ValueError(f"{name} must be None or a finite number >= 0, got {value!r}")
        for name in ("tau_c", "tau_s", "lr"):
            value = getattr(self, name)
            if not _is_number(value) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        if not _is_number(self.weight_decay) or not math.isfinite(self.weight_decay) or self.weight_decay < 0:
            raise ValueError(f"weight_decay must be a finite number >= 0, got {self.weight_decay!r}")
        if not _is_int(self.epochs) or self.epochs < 1:
            raise ValueError(f"epochs must be an integer >= 1, got {self.epochs!r}")
        if not _is_int(self.seed) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")
        try:
            dims = tuple(self.dims)
        except TypeError:
            raise ValueError(f"dims must be a sequence of integers >= 2, got {self.dims!r}") from None
        if not dims or not all(_is_int(m) and m >= 2 for m in dims):
            raise ValueError(f"dims must be a non-empty sequence of integers >= 2, got {self.dims!r}")
        object.__setattr__(self, "dims", tuple(int(m) for m in dims))

    @property
    def lam_value(self) -> float:
        """lambda in effect: ``lam`` or ``1 x batch_size``."""
        return float(self.batch_size if self.lam is None else self.lam)

    @property
    def gamma_value(self) -> float:
        """gamma in effect: ``gamma`` or ``0.01 x batch_size``."""
        return float(0.01 * self.batch_size if self.gamma is None else self.gamma)

    @property
    def t_min_value(self) -> float:
        """T_min in effect: ``t_min`` or ``batch_size / 10``."""
        return float(self.batch_size / 10 if self.t_min is None else self.t_min)

    def params(self) -> dict[str, float | int | str]:
        """Flat, MLflow-ready parameters with the ``None`` rules resolved."""
        return {
            "batch_size": self.batch_size, "lam": self.lam_value, "gamma": self.gamma_value,
            "tau_c": float(self.tau_c), "tau_s": float(self.tau_s), "t_min": self.t_min_value,
            "epochs": self.epochs, "lr": float(self.lr), "weight_decay": float(self.weight_decay),
            "seed": self.seed, "dims": ",".join(str(m) for m in self.dims), "optimizer": "adam",
        }


# ------------------------------------------------------------------ feature layout


@dataclass(frozen=True)
class FeatureLayout:
    """The ordered named segments of the RN input vector x, e.g. ``(("x_manip", 784), ("te", 384))``."""

    segments: tuple[tuple[str, int], ...]
    """``(name, length)`` pairs in vector order."""

    def __post_init__(self) -> None:
        try:
            segments = tuple((name, length) for name, length in self.segments)
        except (TypeError, ValueError):
            raise ValueError(f"segments must be (name, length) pairs, got {self.segments!r}") from None
        if not segments:
            raise ValueError("a feature layout needs at least one segment")
        names = [name for name, _ in segments]
        for name, length in segments:
            if not isinstance(name, str) or not name:
                raise ValueError(f"segment name must be a non-empty string, got {name!r}")
            if not _is_int(length) or length < 1:
                raise ValueError(f"segment {name!r} must have an integer length >= 1, got {length!r}")
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate segment names in feature layout: {names}")
        object.__setattr__(self, "segments", tuple((n, int(k)) for n, k in segments))

    @property
    def dim(self) -> int:
        """Total length of x."""
        return sum(length for _, length in self.segments)

    def slice(self, name: str) -> slice:
        """The slice of x holding segment ``name``."""
        start = 0
        for seg, length in self.segments:
            if seg == name:
                return slice(start, start + length)
            start += length
        raise KeyError(f"unknown feature segment {name!r}; known: {', '.join(n for n, _ in self.segments)}")

    def describe(self) -> str:
        """``x_manip 784 | te 384 | ... = 1680``."""
        return " | ".join(f"{n} {k}" for n, k in self.segments) + f" = {self.dim}"

    def check(self, x: Any) -> np.ndarray:
        """:func:`check_features` of ``x`` against this layout."""
        return check_features(x, self)

    def to_json(self) -> str:
        """JSON text ``{"segments": [[name, length], ...]}``."""
        return json.dumps({"segments": [[n, k] for n, k in self.segments]})

    @classmethod
    def from_json(cls, text: str) -> FeatureLayout:
        """Inverse of :meth:`to_json`."""
        try:
            raw = json.loads(text)
            segments = raw["segments"]
        except (json.JSONDecodeError, TypeError, KeyError) as exc:
            raise ValueError(f"not a feature layout JSON ({exc}): {str(text)[:200]!r}") from None
        return cls(tuple(tuple(s) for s in segments))


def _as_features(x: Any, name: str, expected: int | None = None) -> np.ndarray:
    """``x`` as a float32 (N, D) array; ValueError for a wrong shape/length, an empty set or non-finite values."""
    arr = x.detach().cpu().numpy() if isinstance(x, Tensor) else np.asarray(x)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D (samples, features) array, got shape {arr.shape}")
    if arr.shape[0] == 0:
        raise ValueError(f"{name} is empty (0 samples)")
    if expected is not None and arr.shape[1] != expected:
        raise ValueError(f"{name} has feature length {arr.shape[1]}, expected {expected}")
    if not np.issubdtype(arr.dtype, np.number) or np.issubdtype(arr.dtype, np.complexfloating):
        raise ValueError(f"{name} must hold real numbers, got dtype {arr.dtype}")
    arr = arr.astype(np.float32, copy=False)
    bad = ~np.isfinite(arr)
    if bad.any():
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"{name} has {int(bad.sum())} non-finite (NaN/inf) values, first at row {row}, "
                         f"feature {col}: {arr[row, col]}")
    return arr


def check_features(x: Any, layout: FeatureLayout) -> np.ndarray:
    """``x`` as float32 (N, layout.dim); ValueError naming the expected and given length, or a NaN."""
    arr = x.detach().cpu().numpy() if isinstance(x, Tensor) else np.asarray(x)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim == 2 and arr.shape[1] != layout.dim:
        raise ValueError(f"feature vector has length {arr.shape[1]}, but the layout expects {layout.dim} "
                         f"({layout.describe()})")
    return _as_features(arr, "x", layout.dim)


def _as_labels(y: Any, dims: Sequence[int], name: str) -> np.ndarray:
    """``y`` as int64 (N, n) with ``0 <= y[:, i] < m_i``; ValueError naming a bad dimension and value."""
    arr = y.detach().cpu().numpy() if isinstance(y, Tensor) else np.asarray(y)
    n = len(dims)
    if arr.ndim != 2 or arr.shape[1] != n:
        raise ValueError(f"{name} must have shape (samples, {n}), got {arr.shape}")
    if arr.shape[0] == 0:
        raise ValueError(f"{name} is empty (0 samples)")
    if not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{name} must hold integer class indices, got dtype {arr.dtype}")
    for i, m in enumerate(dims):
        col = arr[:, i]
        bad = np.flatnonzero((col < 0) | (col >= m))
        if bad.size:
            row = int(bad[0])
            hint = " (-1 means 'no label': drop those samples first)" if col[row] == -1 else ""
            raise ValueError(f"{name}: dimension a{i} has {m} choices (0..{m - 1}) but holds value {int(col[row])} "
                             f"at row {row} ({bad.size} bad rows){hint}")
    return arr.astype(np.int64, copy=False)


# ------------------------------------------------------------------ network


class RepresentationNetwork(nn.Module):
    """Table I: three Linear-BatchNorm1d-ReLU-Dropout blocks (512/256/128; p 0.5/0.5/0.4), then
    ``Linear(128, sum(dims))``. Inputs are standardised by the ``x_mean``/``x_std`` buffers (set from
    the training set by :func:`train_rn`; identity until then) before the first layer. ``config`` and
    ``layout`` are set by :func:`train_rn` / :func:`load_rn` (``None`` on a bare network); the caller sets
    ``plan_libraries``, ``plan_priors`` and ``pointnet_sha256``, which :func:`save_rn` stores and
    :func:`load_rn` restores."""

    def __init__(self, in_dim: int, dims: Sequence[int] = RS_DIMS) -> None:
        super().__init__()
        if not _is_int(in_dim) or in_dim < 1:
            raise ValueError(f"in_dim must be an integer >= 1, got {in_dim!r}")
        if not len(dims) or not all(_is_int(m) and m >= 2 for m in dims):
            raise ValueError(f"dims must be a non-empty sequence of integers >= 2, got {dims!r}")
        self.in_dim = int(in_dim)
        self.dims: tuple[int, ...] = tuple(int(m) for m in dims)
        layers: list[nn.Module] = []
        width = self.in_dim
        for hidden, p in zip(HIDDEN, DROPOUT, strict=True):
            layers += [nn.Linear(width, hidden), nn.BatchNorm1d(hidden), nn.ReLU(), nn.Dropout(p=p)]
            width = hidden
        layers.append(nn.Linear(width, sum(self.dims)))
        self.layers = nn.Sequential(*layers)
        self.register_buffer("x_mean", torch.zeros(self.in_dim))
        self.register_buffer("x_std", torch.ones(self.in_dim))
        self.config: RNConfig | None = None
        self.layout: FeatureLayout | None = None
        self.plan_libraries: dict[str, np.ndarray] = {}
        """Per task, the (K, n) demonstrated plans for :func:`library_plan` decoding (set by the caller with
        :func:`plan_libraries`; saved with the model)."""
        self.plan_priors: dict[str, tuple[np.ndarray, ...]] = {}
        """Per task, the per-dimension probabilities the demos' plans were sampled with (``library_plan``'s
        ``prior``), kept with the model so a later change of the catalogue does not change its decoding."""
        self.pointnet_sha256: str | None = None
        """SHA-256 of the PointNet checkpoint whose features the model was trained on (``None``: unknown)."""

    def set_standardisation(self, mean: np.ndarray | Tensor, std: np.ndarray | Tensor) -> None:
        """Set the input standardisation ``(x - mean) / std`` (std entries below ``STD_FLOOR`` -> 1)."""
        mean_t = torch.as_tensor(np.asarray(mean, dtype=np.float32)).reshape(-1)
        std_t = torch.as_tensor(np.asarray(std, dtype=np.float32)).reshape(-1)
        if mean_t.numel() != self.in_dim or std_t.numel() != self.in_dim:
            raise ValueError(f"standardisation needs {self.in_dim} values, got mean {mean_t.numel()}, "
                             f"std {std_t.numel()}")
        self.x_mean.copy_(mean_t)
        self.x_std.copy_(torch.where(std_t < STD_FLOOR, torch.ones_like(std_t), std_t))

    def forward(self, x: Tensor) -> Tensor:
        """Logits (B, sum(dims)) from raw features x (B, in_dim)."""
        if x.ndim != 2 or x.shape[1] != self.in_dim:
            raise ValueError(f"RN input must have shape (batch, {self.in_dim}), got {tuple(x.shape)}")
        return self.layers((x - self.x_mean) / self.x_std)


def split_logits(logits: Tensor, dims: Sequence[int]) -> list[Tensor]:
    """Split (B, sum(dims)) logits into one (B, m_i) tensor per dimension."""
    if logits.shape[-1] != sum(dims):
        raise ValueError(f"logits have {logits.shape[-1]} columns, dims {tuple(dims)} need {sum(dims)}")
    return list(torch.split(logits, list(dims), dim=-1))


# ------------------------------------------------------------------ Eq 3


def rn_loss(logits_per_dim: Sequence[Tensor], targets: Tensor, cfg: RNConfig) -> dict[str, Tensor]:
    """Eq 3 term by term for one batch (see the module docstring for the reductions).

    ``logits_per_dim``: n tensors (B, m_i); ``targets``: long (B, n). Returns scalar tensors
    ``ce`` (cross-entropy summed over the batch and the dims), ``confidence`` (lambda x sum over dims
    of the batch-mean hinge ``max(0, tau_c/m_i - p_max)``), ``count`` (gamma x 1{C < T_min}, no
    gradient), ``total`` (their sum), and the diagnostics ``n_confident`` (C, the number of
    (sample, dim) pairs with ``p_max > tau_s/m_i``) and ``count_on`` (the indicator, 0 or 1)."""
    n = len(logits_per_dim)
    if targets.ndim != 2 or targets.shape[1] != n:
        raise ValueError(f"targets must have shape (batch, {n}), got {tuple(targets.shape)}")
    widths = tuple(int(lg.shape[-1]) for lg in logits_per_dim)
    if widths != cfg.dims:
        raise ValueError(f"logit widths {widths} do not match cfg.dims {cfg.dims}")
    batch = targets.shape[0]
    if batch == 0 or any(lg.ndim != 2 or lg.shape[0] != batch for lg in logits_per_dim):
        raise ValueError(f"every logit tensor must be (batch={batch} > 0, m_i), got "
                         f"{[tuple(lg.shape) for lg in logits_per_dim]}")
    ce = logits_per_dim[0].new_zeros(())
    hinge = logits_per_dim[0].new_zeros(())
    n_confident = logits_per_dim[0].new_zeros(())
    for i, (logits, m) in enumerate(zip(logits_per_dim, widths, strict=True)):
        t = targets[:, i]
        if bool(((t < 0) | (t >= m)).any()):
            bad = int(t[(t < 0) | (t >= m)][0])
            raise ValueError(f"target of dimension a{i} is {bad}, outside 0..{m - 1}")
        ce = ce + F.cross_entropy(logits, t, reduction="sum")
        p_max = torch.softmax(logits, dim=-1).amax(dim=-1)
        hinge = hinge + torch.clamp(cfg.tau_c / m - p_max, min=0.0).mean()
        n_confident = n_confident + (p_max.detach() > cfg.tau_s / m).sum()
    count_on = (n_confident < cfg.t_min_value).to(ce.dtype)
    confidence = cfg.lam_value * hinge
    count = (cfg.gamma_value * count_on).detach()
    return {"ce": ce, "confidence": confidence, "count": count, "total": ce + confidence + count,
            "n_confident": n_confident.to(ce.dtype), "count_on": count_on}


# ------------------------------------------------------------------ training


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


@torch.no_grad()
def _logits(model: RepresentationNetwork, x: Tensor) -> Tensor:
    was_training = model.training
    model.eval()
    try:
        return torch.cat([model(x[s : s + PREDICT_CHUNK]) for s in range(0, len(x), PREDICT_CHUNK)])
    finally:
        model.train(was_training)


def _accuracy(model: RepresentationNetwork, x: Tensor, y: Tensor) -> np.ndarray:
    parts = split_logits(_logits(model, x), model.dims)
    return np.array([float((p.argmax(dim=-1) == y[:, i]).float().mean()) for i, p in enumerate(parts)])


def train_rn(
    x_train: Any,
    y_train: Any,
    cfg: RNConfig | None = None,
    x_val: Any = None,
    y_val: Any = None,
    on_epoch: Callable[[int, dict[str, float]], None] | None = None,
    progress: bool = True,
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
    for a given torch thread count."""
    cfg = RNConfig() if cfg is None else cfg
    x = _as_features(x_train, "x_train")
    y = _as_labels(y_train, cfg.dims, "y_train")
    if len(x) != len(y):
        raise ValueError(f"x_train has {len(x)} samples but y_train has {len(y)}")
    if len(x) < 2:
        raise ValueError(f"RN training needs at least 2 samples (BatchNorm1d), got {len(x)}")
    if (x_val is None) != (y_val is None):
        raise ValueError("give both x_val and y_val, or neither")
    xv_t = yv_t = None
    if x_val is not None:
        xv = _as_features(x_val, "x_val", x.shape[1])
        yv = _as_labels(y_val, cfg.dims, "y_val")
        if len(xv) != len(yv):
            raise ValueError(f"x_val has {len(xv)} samples but y_val has {len(yv)}")
        xv_t, yv_t = torch.from_numpy(xv), torch.from_numpy(yv)
    x_t, y_t = torch.from_numpy(x), torch.from_numpy(y)
    mean, std = feature_stats(x)
    rng = np.random.default_rng(cfg.seed)
    history: list[dict[str, float]] = []

    from tqdm.auto import tqdm

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
                terms = rn_loss(parts, y_t[index], cfg)
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
                logits = _logits(model, xv_t)
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


# ------------------------------------------------------------------ prediction


def predict_proba(model: RepresentationNetwork, x: Any) -> list[np.ndarray]:
    """Per dimension, the (N, m_i) predicted probabilities for raw features x (N, in_dim) (eval mode)."""
    arr = _as_features(np.asarray(x)[None, :] if np.ndim(x) == 1 else x, "x", model.in_dim)
    parts = split_logits(_logits(model, torch.from_numpy(arr)), model.dims)
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
    dims = [p.shape[1] for p in probs]
    lib = check_library(library, dims)
    # (N, K) scores; the floor keeps log finite where a probability underflows to 0
    score = sum(np.log(np.maximum(p, 1e-30))[:, lib[:, i]] for i, p in enumerate(probs))
    if prior is not None:
        score = score - sum(np.log(q)[lib[:, i]] for i, q in enumerate(check_prior(prior, dims)))
    return lib[np.argmax(score, axis=1)]


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
    labels = _as_labels(y, model.dims, "y")
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


def key_dimensions(probs: Sequence[np.ndarray], tau: float = 2.0) -> list[DimensionSummary]:
    """Summarise per-dimension probabilities ``probs[i]`` (N, m_i) of one task (see the module docstring).

    A dimension is key when the largest entry of its mean probability vector exceeds ``tau / m_i``
    (default ``tau`` = the paper's ``tau_s`` = 2: twice the uniform probability). The mean over
    samples is used, not each sample's maximum, so that confident but disagreeing predictions (no
    shared rule) do not count."""
    if not _is_number(tau) or not tau > 0:
        raise ValueError(f"tau must be a number > 0, got {tau!r}")
    out = []
    for i, p in enumerate(probs):
        arr = np.asarray(p, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] < 2:
            raise ValueError(f"probs[{i}] must be (samples > 0, choices >= 2), got shape {arr.shape}")
        mean = arr.mean(axis=0)
        top = int(mean.argmax())
        threshold = tau / arr.shape[1]
        out.append(DimensionSummary(index=i, mean_probs=mean, mean_max_prob=float(arr.max(axis=1).mean()),
                                    top_choice=top, top_prob=float(mean[top]), threshold=threshold,
                                    key=bool(mean[top] > threshold)))
    return out


# ------------------------------------------------------------------ checkpoints


def save_rn(model: RepresentationNetwork, cfg: RNConfig, layout: FeatureLayout, path: str | Path) -> Path:
    """Write the model, its config, its input layout, its ``plan_libraries``, ``plan_priors`` and
    ``pointnet_sha256`` to ``path`` (torch file); return the path."""
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
    path.parent.mkdir(parents=True, exist_ok=True)
    cfg_dict = asdict(cfg) | {"dims": list(cfg.dims)}
    payload = {"format": CHECKPOINT_FORMAT, "in_dim": model.in_dim, "dims": list(model.dims),
               "config": cfg_dict, "layout": layout.to_json(), "plan_libraries": libraries, "plan_priors": priors,
               "pointnet_sha256": model.pointnet_sha256,
               "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()}}
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)
    return path


def load_rn(path: str | Path, expected_layout: FeatureLayout | None = None) -> RepresentationNetwork:
    """Read a :func:`save_rn` checkpoint: the model in eval mode, with ``model.config`` and ``model.layout``.

    FileNotFoundError names a missing path; ValueError names both layouts when ``expected_layout``
    differs from the stored one, or says what is wrong with a file that is not an RN checkpoint."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"RN checkpoint not found: {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many kinds for a bad file
        raise ValueError(f"{path} is not a readable RN checkpoint: {exc}") from exc
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        got = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise ValueError(f"{path} is not an RN checkpoint of format {CHECKPOINT_FORMAT!r} (got {got!r})")
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
