"""PointNet encoder PN: a 256-d shape feature of a tool or object point cloud (the RN input's PN parts).

Architecture (Qi et al. 2017, without the T-nets): a per-point MLP shared across points (``Conv1d``
with kernel 1 + BatchNorm + ReLU for each of ``channels``), a global max-pool over points, then the
``head`` MLP (Linear + BatchNorm + ReLU).  The last head layer is the feature (``features()``,
``feature_dim`` = ``PN_DIM`` wide); two linear output heads sit on it:

* ``category`` logits over ``prl.shapes.SHAPE_CATEGORIES`` (cross-entropy, ``loss_ce``);
* ``size``: the natural log of the cloud's axis-aligned bounding-box extents in metres, ``(3,)`` in
  the cloud's own axes (MSE, ``loss_size``).  Log-metres make a 5 % error cost the same at 2 mm and
  at 30 cm; ``val_size_err_pct`` reports the mean ``|exp(pred - target) - 1|`` in per cent.

The encoder is pre-trained on synthetic shapes (``make_shape_dataset``): clouds from
``prl.shapes.sample_points``, centred but not scaled.  With ``scale_input`` (default) the network
sees each cloud as ``(p / s, log s)`` per point, ``s`` the cloud's largest point norm: the shape at a
common scale plus its size as an explicit channel, so a 2 mm and a 30 cm box are recognised alike
and the feature still knows their sizes.  With ``random_axes`` each shape is first turned by one of
the 24 rotations that map the axes onto signed axes (the env meshes are axis-aligned, but a tool's
long axis may be any of them).

Profiles (``pointnet_config(profile)``), compute ~linear in ``n_shapes * epochs * n_points``:

* ``quick`` (the dataclass defaults: 640 shapes, 512 points, 6 epochs): ~45 CPU-seconds on one
  thread (~8 s of it generating the shapes), held-out category accuracy ~0.52 (chance 0.125), size
  error ~32 %;
* ``paper`` (4,000 shapes, 30 epochs, as the pipeline's ``paper`` profile): ~31x the quick
  compute, ~25 min on one CPU thread, minutes on a GPU.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from prl.shapes import SHAPE_CATEGORIES, random_shape, sample_points

#: Width of the PointNet feature that enters the Representation Network.
PN_DIM = 256
#: Smallest cloud radius (m) ``scale_input`` divides by (guards a degenerate all-zero cloud).
_MIN_SCALE = 1e-5
#: Version of the checkpoint layout written by ``save_pointnet``.
CHECKPOINT_FORMAT = 1


@dataclass(frozen=True)
class PointNetConfig:
    """Architecture and pre-training settings of the PointNet encoder (defaults: the ``quick`` profile)."""

    n_points: int = 512
    """Surface points per cloud."""
    channels: tuple[int, ...] = (64, 128, 256)
    """Widths of the shared per-point MLP layers."""
    head: tuple[int, ...] = (256,)
    """Widths of the MLP after the max-pool; the last one is the feature layer."""
    feature_dim: int = PN_DIM
    """Width of ``features()``; must equal ``head[-1]`` (or ``channels[-1]`` when ``head`` is empty)."""
    categories: tuple[str, ...] = SHAPE_CATEGORIES
    """Shape categories to classify, each one of ``prl.shapes.SHAPE_CATEGORIES``."""
    n_shapes: int = 640
    """Synthetic training shapes (categories balanced)."""
    n_val: int = 256
    """Held-out synthetic shapes, drawn from a separate random stream."""
    epochs: int = 6
    """Passes over the training shapes."""
    batch_size: int = 32
    """Shapes per optimiser step."""
    lr: float = 2e-3
    """Adam learning rate (cosine-annealed to zero over the run)."""
    weight_decay: float = 1e-4
    """Adam weight decay."""
    size_loss_weight: float = 1.0
    """Weight of the log-extent MSE against the cross-entropy."""
    random_axes: bool = True
    """Turn each synthetic shape by a random axis-to-axis rotation (one of 24)."""
    scale_input: bool = True
    """Feed ``(p / s, log s)`` per point, ``s`` the cloud's largest point norm (m), instead of raw ``p``."""
    seed: int = 0
    """Seed of the data, the initial weights and the batch order."""

    def __post_init__(self) -> None:
        for name in ("n_points", "feature_dim", "n_shapes", "n_val", "epochs", "batch_size"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        for name in ("channels", "head"):
            value = tuple(getattr(self, name))
            if any(not isinstance(v, int) or v <= 0 for v in value):
                raise ValueError(f"{name} must hold positive integers, got {getattr(self, name)!r}")
            object.__setattr__(self, name, value)
        if not self.channels:
            raise ValueError("channels is empty; give at least one per-point layer width")
        last = self.head[-1] if self.head else self.channels[-1]
        if last != self.feature_dim:
            raise ValueError(
                f"feature_dim {self.feature_dim!r} must equal the last layer width {last} "
                f"(head={self.head!r}, channels={self.channels!r})"
            )
        object.__setattr__(self, "categories", tuple(self.categories))
        unknown = [c for c in self.categories if c not in SHAPE_CATEGORIES]
        if unknown or len(self.categories) < 2 or len(set(self.categories)) != len(self.categories):
            raise ValueError(
                f"categories must be >= 2 distinct names from {SHAPE_CATEGORIES}, got {self.categories!r}"
            )
        for name in ("lr", "size_loss_weight"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if not self.weight_decay >= 0:
            raise ValueError(f"weight_decay must be >= 0, got {self.weight_decay!r}")
        if not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")


#: Named settings; ``quick`` is the dataclass defaults.
POINTNET_PROFILES: dict[str, dict[str, Any]] = {
    "quick": {},
    "paper": {"n_shapes": 4000, "n_val": 512, "epochs": 30, "lr": 1e-3},
}


def pointnet_config(profile: str = "quick", **overrides: Any) -> PointNetConfig:
    """The named profile's config with ``overrides`` (``None`` values ignored) applied."""
    if profile not in POINTNET_PROFILES:
        raise ValueError(f"unknown PointNet profile {profile!r}; known: {sorted(POINTNET_PROFILES)}")
    settings = {**POINTNET_PROFILES[profile], **{k: v for k, v in overrides.items() if v is not None}}
    return replace(PointNetConfig(), **settings)


# ------------------------------------------------------------------ model


class PointNetEncoder(nn.Module):
    """Shared per-point MLP -> max-pool -> head MLP (the feature) -> category logits and log extents."""

    def __init__(self, cfg: PointNetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        layers: list[nn.Module] = []
        width = 4 if cfg.scale_input else 3
        for out in cfg.channels:
            layers += [nn.Conv1d(width, out, kernel_size=1), nn.BatchNorm1d(out), nn.ReLU()]
            width = out
        self.point_mlp = nn.Sequential(*layers)
        layers = []
        for out in cfg.head:
            layers += [nn.Linear(width, out), nn.BatchNorm1d(out), nn.ReLU()]
            width = out
        self.head_mlp = nn.Sequential(*layers)
        self.category_head = nn.Linear(width, len(cfg.categories))
        self.size_head = nn.Linear(width, 3)

    def features(self, points: torch.Tensor) -> torch.Tensor:
        """``(B, feature_dim)`` feature of ``(B, P, 3)`` clouds (metres): the layer before the output heads."""
        if points.ndim != 3 or points.shape[-1] != 3:
            raise ValueError(f"points must be (batch, n_points, 3), got shape {tuple(points.shape)}")
        x = points.transpose(1, 2)
        if self.cfg.scale_input:
            scale = x.norm(dim=1, keepdim=True).amax(dim=2, keepdim=True).clamp_min(_MIN_SCALE)
            x = torch.cat([x / scale, torch.log(scale).expand(-1, 1, x.shape[2])], dim=1)
        pooled = self.point_mlp(x).amax(dim=2)
        return self.head_mlp(pooled)

    def forward(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(category logits (B, C), log bounding-box extents in metres (B, 3))``."""
        feat = self.features(points)
        return self.category_head(feat), self.size_head(feat)


# ------------------------------------------------------------------ data


def _stream_seed(seed: int, stream: int) -> int:
    """An independent 32-bit seed for random stream ``stream`` of run seed ``seed``."""
    return int(np.random.SeedSequence([seed, stream]).generate_state(1)[0])


def _axis_rotations() -> np.ndarray:
    """The 24 proper rotations (``(24, 3, 3)``) that map the coordinate axes onto signed axes."""
    out = []
    for perm in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        for signs in np.ndindex(2, 2, 2):
            R = np.zeros((3, 3))
            R[np.arange(3), perm] = 1 - 2 * np.array(signs)
            if np.linalg.det(R) > 0:
                out.append(R)
    return np.stack(out)


def make_shape_dataset(
    cfg: PointNetConfig, seed: int, n: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` (default ``cfg.n_shapes``) synthetic shapes: ``(points (n, n_points, 3) float32, category (n,)
    int64 index into cfg.categories, extents (n, 3) float32 bounding-box extents in metres)``.

    Categories are balanced (``i % n_categories``, shuffled); each shape comes from
    ``prl.shapes.random_shape``, optionally turned (``cfg.random_axes``), then ``sample_points``.
    Deterministic for ``(cfg, seed, n)``.
    """
    n = cfg.n_shapes if n is None else n
    if not isinstance(n, int) or n <= 0:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    rng = np.random.default_rng(seed)
    rotations = _axis_rotations()
    category = rng.permutation(np.arange(n) % len(cfg.categories)).astype(np.int64)
    points = np.empty((n, cfg.n_points, 3), dtype=np.float32)
    extents = np.empty((n, 3), dtype=np.float32)
    for i, k in enumerate(category):
        mesh = random_shape(cfg.categories[k], rng)
        if cfg.random_axes:
            transform = np.eye(4)
            transform[:3, :3] = rotations[rng.integers(len(rotations))]
            mesh.apply_transform(transform)
        points[i] = sample_points(mesh, cfg.n_points, int(rng.integers(2**31)))
        extents[i] = mesh.extents
    return points, category, extents


# ------------------------------------------------------------------ training


def _evaluate(model: PointNetEncoder, points: torch.Tensor, category: torch.Tensor,
              log_ext: torch.Tensor, batch_size: int) -> dict[str, float]:
    """Held-out ``val_*`` metrics of ``model`` (eval mode, no grad)."""
    model.eval()
    logits, sizes = [], []
    with torch.no_grad():
        for start in range(0, len(points), batch_size):
            lg, sz = model(points[start:start + batch_size])
            logits.append(lg)
            sizes.append(sz)
    logit, size = torch.cat(logits), torch.cat(sizes)
    return {
        "val_loss_ce": float(F.cross_entropy(logit, category)),
        "val_loss_size": float(F.mse_loss(size, log_ext)),
        "val_acc": float((logit.argmax(1) == category).float().mean()),
        "val_size_err_pct": float(100 * (torch.exp(size - log_ext) - 1).abs().mean()),
    }


def train_pointnet(
    cfg: PointNetConfig, on_epoch: Callable[[int, dict[str, float]], None] | None = None
) -> tuple[PointNetEncoder, dict[str, list[float]]]:
    """Pre-train a ``PointNetEncoder`` on synthetic shapes; returns ``(model in eval mode, history)``.

    Loss = ``loss_ce`` (category cross-entropy) + ``size_loss_weight * loss_size`` (MSE of the log
    extents), Adam with a cosine learning-rate decay.  ``history`` maps each metric to its per-epoch
    values (lists, JSON-ready; callers namespace them, e.g. ``pn/val_acc``): the training means
    ``loss``, ``loss_ce``, ``loss_size``, ``train_acc``; on the held-out shapes ``val_loss_ce``,
    ``val_loss_size``, ``val_acc`` (chance is ``1 / len(cfg.categories)``), ``val_size_err_pct``; and
    ``elapsed_s``, wall seconds since the start (data generation included).  ``on_epoch(epoch,
    metrics)`` receives each epoch's values.  Deterministic given ``cfg`` and the torch thread count.
    """
    t0 = time.perf_counter()
    train = make_shape_dataset(cfg, _stream_seed(cfg.seed, 0), cfg.n_shapes)
    val = make_shape_dataset(cfg, _stream_seed(cfg.seed, 1), cfg.n_val)

    def tensors(data: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[torch.Tensor, ...]:
        pts, cat, ext = data
        return torch.from_numpy(pts), torch.from_numpy(cat), torch.log(torch.from_numpy(ext))

    x_tr, c_tr, s_tr = tensors(train)
    x_va, c_va, s_va = tensors(val)

    torch.manual_seed(_stream_seed(cfg.seed, 2))
    model = PointNetEncoder(cfg)
    optimiser = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    steps_per_epoch = -(-cfg.n_shapes // cfg.batch_size)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=cfg.epochs * steps_per_epoch)
    order_gen = torch.Generator().manual_seed(_stream_seed(cfg.seed, 3))

    history: dict[str, list[float]] = {}
    for epoch in range(cfg.epochs):
        model.train()
        order = torch.randperm(cfg.n_shapes, generator=order_gen)
        sums = {"loss": 0.0, "loss_ce": 0.0, "loss_size": 0.0, "train_acc": 0.0}
        seen = 0
        for start in range(0, cfg.n_shapes, cfg.batch_size):
            idx = order[start:start + cfg.batch_size]
            if len(idx) < 2:  # BatchNorm needs two samples
                continue
            logits, sizes = model(x_tr[idx])
            loss_ce = F.cross_entropy(logits, c_tr[idx])
            loss_size = F.mse_loss(sizes, s_tr[idx])
            loss = loss_ce + cfg.size_loss_weight * loss_size
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            seen += len(idx)
            sums["loss"] += float(loss.detach()) * len(idx)
            sums["loss_ce"] += float(loss_ce.detach()) * len(idx)
            sums["loss_size"] += float(loss_size.detach()) * len(idx)
            sums["train_acc"] += float((logits.argmax(1) == c_tr[idx]).float().sum())
        metrics = {key: value / max(seen, 1) for key, value in sums.items()}
        metrics.update(_evaluate(model, x_va, c_va, s_va, cfg.batch_size * 4))
        metrics["elapsed_s"] = time.perf_counter() - t0
        for key, value in metrics.items():
            history.setdefault(key, []).append(value)
        if on_epoch is not None:
            on_epoch(epoch, metrics)
    model.eval()
    return model, history


# ------------------------------------------------------------------ inference and checkpoints


def encode_points(model: PointNetEncoder, points: np.ndarray, batch_size: int = 256) -> np.ndarray:
    """float32 features ``(n, feature_dim)`` of clouds ``(n, P, 3)`` (a single ``(P, 3)`` cloud gives n = 1).

    Runs in eval mode without gradients, ``batch_size`` clouds at a time; the model's train/eval mode
    is restored afterwards.  ``P`` need not equal ``cfg.n_points`` (the max-pool takes any count).
    """
    arr = np.asarray(points, dtype=np.float32)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[-1] != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"points must be (n, n_points, 3) or (n_points, 3), got shape {np.shape(points)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("points contain NaN or inf")
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad():
            feats = [model.features(torch.from_numpy(arr[s:s + batch_size])) for s in range(0, len(arr), batch_size)]
    finally:
        model.train(was_training)
    return torch.cat(feats).numpy().astype(np.float32, copy=False)


def save_pointnet(model: PointNetEncoder, cfg: PointNetConfig, path: str | Path) -> Path:
    """Write ``model``'s weights with ``cfg``, the feature width and ``CHECKPOINT_FORMAT`` to ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(
        {
            "format": CHECKPOINT_FORMAT,
            "feature_dim": cfg.feature_dim,
            "config": asdict(cfg),
            "state_dict": model.state_dict(),
        },
        path,
    )
    return path


def load_pointnet(path: str | Path, feature_dim: int = PN_DIM) -> PointNetEncoder:
    """The ``save_pointnet`` model at ``path``, in eval mode (its config is ``model.cfg``).

    ``FileNotFoundError`` naming ``path`` when it is missing; ``ValueError`` when the file's format
    version is unknown, its config has fields this code does not know, or its feature width is not
    ``feature_dim``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"PointNet checkpoint not found: {str(path)!r}")
    blob = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(blob, dict) or blob.get("format") != CHECKPOINT_FORMAT:
        found = blob.get("format") if isinstance(blob, dict) else type(blob).__name__
        raise ValueError(f"{str(path)!r} is not a PointNet checkpoint of format {CHECKPOINT_FORMAT} (found {found!r})")
    if blob["feature_dim"] != feature_dim:
        raise ValueError(f"{str(path)!r} has feature_dim {blob['feature_dim']!r}, expected {feature_dim}")
    known = {f.name for f in fields(PointNetConfig)}
    unknown = sorted(set(blob["config"]) - known)
    if unknown:
        raise ValueError(f"{str(path)!r} has config fields {unknown} that PointNetConfig does not know")
    cfg = PointNetConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in blob["config"].items()})
    model = PointNetEncoder(cfg)
    model.load_state_dict(blob["state_dict"])
    model.eval()
    return model
