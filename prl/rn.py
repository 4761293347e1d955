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

Inputs are standardised with the training set's mean/std, stored as buffers in the model, so every
prediction takes raw ``x``. Training is ``prl.rn_train``, decoding a plan from the heads and the key
dimensions of Fig 7 ``prl.rn_decode``, checkpoints ``prl.rn_checkpoint``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
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
#: Rows per forward pass in :func:`eval_logits` (and so in the prediction helpers).
PREDICT_CHUNK = 4096


def is_int(value: object) -> bool:
    """An integer (Python or numpy), not a bool."""
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def is_number(value: object) -> bool:
    """A real number (Python or numpy), not a bool."""
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
        if not is_int(self.batch_size) or self.batch_size < 2:
            raise ValueError(f"batch_size must be an integer >= 2 (BatchNorm1d), got {self.batch_size!r}")
        for name in ("lam", "gamma", "t_min"):
            value = getattr(self, name)
            if value is not None and (not is_number(value) or not math.isfinite(value) or value < 0):
                raise ValueError(f"{name} must be None or a finite number >= 0, got {value!r}")
        for name in ("tau_c", "tau_s", "lr"):
            value = getattr(self, name)
            if not is_number(value) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        if not is_number(self.weight_decay) or not math.isfinite(self.weight_decay) or self.weight_decay < 0:
            raise ValueError(f"weight_decay must be a finite number >= 0, got {self.weight_decay!r}")
        if not is_int(self.epochs) or self.epochs < 1:
            raise ValueError(f"epochs must be an integer >= 1, got {self.epochs!r}")
        if not is_int(self.seed) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")
        try:
            dims = tuple(self.dims)
        except TypeError:
            raise ValueError(f"dims must be a sequence of integers >= 2, got {self.dims!r}") from None
        if not dims or not all(is_int(m) and m >= 2 for m in dims):
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
            if not is_int(length) or length < 1:
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


def as_features(x: Any, name: str, expected: int | None = None) -> np.ndarray:
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
    return as_features(arr, "x", layout.dim)


def as_labels(y: Any, dims: Sequence[int], name: str) -> np.ndarray:
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
    the training set by ``prl.rn_train.train_rn``; identity until then) before the first layer. ``config``
    and ``layout`` are set by ``train_rn`` / ``prl.rn_checkpoint.load_rn`` (``None`` on a bare network); the
    caller sets ``plan_libraries``, ``plan_priors`` and ``pointnet_sha256``, which
    ``prl.rn_checkpoint.save_rn`` stores and ``load_rn`` restores."""

    def __init__(self, in_dim: int, dims: Sequence[int] = RS_DIMS) -> None:
        super().__init__()
        if not is_int(in_dim) or in_dim < 1:
            raise ValueError(f"in_dim must be an integer >= 1, got {in_dim!r}")
        if not len(dims) or not all(is_int(m) and m >= 2 for m in dims):
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
        """Per task, the (K, n) demonstrated plans for ``prl.rn_decode.library_plan`` decoding (set by the
        caller with ``prl.rn_decode.plan_libraries``; saved with the model)."""
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


@torch.no_grad()
def eval_logits(model: RepresentationNetwork, x: Tensor) -> Tensor:
    """Logits of ``x`` in eval mode, ``PREDICT_CHUNK`` rows per pass, the model's mode restored afterwards."""
    was_training = model.training
    model.eval()
    try:
        return torch.cat([model(x[s : s + PREDICT_CHUNK]) for s in range(0, len(x), PREDICT_CHUNK)])
    finally:
        model.train(was_training)


# ------------------------------------------------------------------ Eq 3


def rn_loss(logits_per_dim: Sequence[Tensor], targets: Tensor, cfg: RNConfig,
            weights: Tensor | None = None) -> dict[str, Tensor]:
    """Eq 3 term by term for one batch (see the module docstring for the reductions).

    ``logits_per_dim``: n tensors (B, m_i); ``targets``: long (B, n). Returns scalar tensors
    ``ce`` (cross-entropy summed over the batch and the dims), ``confidence`` (lambda x sum over dims
    of the batch-mean hinge ``max(0, tau_c/m_i - p_max)``), ``count`` (gamma x 1{C < T_min}, no
    gradient), ``total`` (their sum), and the diagnostics ``n_confident`` (C, the number of
    (sample, dim) pairs with ``p_max > tau_s/m_i``) and ``count_on`` (the indicator, 0 or 1).

    ``weights`` (B,): each sample's cross-entropy is multiplied by its weight (the importance weight prior /
    proposal of its plan, ``prl.proposal``: the RN then learns the successful plans of the prior, whatever
    proposal synthesis drew them from); None: all 1."""
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
        ce = ce + (F.cross_entropy(logits, t, reduction="sum") if weights is None
                   else (F.cross_entropy(logits, t, reduction="none") * weights).sum())
        p_max = torch.softmax(logits, dim=-1).amax(dim=-1)
        hinge = hinge + torch.clamp(cfg.tau_c / m - p_max, min=0.0).mean()
        n_confident = n_confident + (p_max.detach() > cfg.tau_s / m).sum()
    count_on = (n_confident < cfg.t_min_value).to(ce.dtype)
    confidence = cfg.lam_value * hinge
    count = (cfg.gamma_value * count_on).detach()
    return {"ce": ce, "confidence": confidence, "count": count, "total": ce + confidence + count,
            "n_confident": n_confident.to(ce.dtype), "count_on": count_on}
