"""The Representation Network's input x = [x_manip, TE(task text), PN(tool points), PN(object points)].

Read from an exported LeRobot dataset (``prl.export``): per episode the constant ``x_manip``,
``plan`` and ``label`` columns, the task sentence, and the scene record (``read_scenes``) from
which the randomised tool and object meshes are rebuilt (``prl.shapes``), sampled into point
clouds and encoded by the trained PointNet (``prl.pointnet``). The same function builds x for a
live scene in simulation (``scene_features``), so training and evaluation see one layout:

=================  ======  ===================================================
segment            length  content
=================  ======  ===================================================
x_manip            784     observation-phase states (``prl.demo``)
text               384     all-MiniLM-L6-v2 embedding of the task sentence
tool_points        256     PointNet feature of the tool's surface points
object_points      256     PointNet feature of the object's surface points
=================  ======  ===================================================
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prl.demo import X_MANIP_DIM
from prl.pointnet import PN_DIM
from prl.stats import importance_weights
from prl.rn import FeatureLayout
from prl.text_embed import TE_DIM, embed_texts

FEATURE_LAYOUT = FeatureLayout((("x_manip", X_MANIP_DIM), ("text", TE_DIM), ("tool_points", PN_DIM),
                                ("object_points", PN_DIM)))
"""The segments of x, in order (1,680 values)."""
PER_EPISODE_COLUMNS: tuple[str, ...] = ("x_manip", "plan", "label")
"""Dataset columns the RN reads (constant within an episode)."""


@dataclass(frozen=True)
class Episodes:
    """What the RN needs of each episode of a dataset, in episode order."""

    tasks: tuple[str, ...]
    """Task name per episode (from the scene record)."""
    texts: tuple[str, ...]
    """Task sentence per episode."""
    seeds: np.ndarray
    """(N,) scene seeds."""
    scene_params: tuple[dict[str, float], ...]
    """Randomised scene values per episode."""
    x_manip: np.ndarray
    """(N, 784) float32."""
    plan: np.ndarray
    """(N, 6) int64 commanded plans (all succeeded in simulation)."""
    label: np.ndarray
    """(N, 6) int64 recovered physical-law labels (-1 where none)."""
    outcomes: tuple[dict[str, Any], ...] = ()
    """The task's evaluation of each episode's final simulated state (from the scene record)."""
    weights: np.ndarray | None = None
    """(N,) importance weights prior / proposal of each episode's plan, mean 1 within each task
    (``demo_weights``; None: all 1)."""

    def __len__(self) -> int:
        return len(self.tasks)


def read_episodes(root: Path | str, repo_id: str) -> Episodes:
    """Per-episode RN inputs of the LeRobot dataset at ``root``; clear errors for a missing piece."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # heavy: lerobot

    from prl.export_check import drop_datasets_cache
    from prl.export_schema import read_scenes

    root = Path(root)
    if not (root / "meta" / "info.json").is_file():
        raise FileNotFoundError(f"no LeRobot dataset at {str(root)!r} (meta/info.json is missing)")
    ds = LeRobotDataset(repo_id, root=root)
    try:
        return _episodes_of(ds, root, read_scenes(root))
    finally:
        drop_datasets_cache(ds)  # loading wrote an Arrow copy (~5x the dataset) into the datasets cache


def _episodes_of(ds: Any, root: Path, scenes: list[dict[str, Any]]) -> Episodes:
    missing = [name for name in PER_EPISODE_COLUMNS if name not in ds.meta.features]
    if missing:
        raise ValueError(f"dataset at {str(root)!r} lacks the feature(s) {missing} that the RN reads")
    eps = ds.meta.episodes
    starts = np.asarray(eps["dataset_from_index"], dtype=np.int64)
    if len(scenes) != len(starts):
        raise ValueError(f"dataset at {str(root)!r} has {len(starts)} episodes but {len(scenes)} scene records")
    if len(starts) == 0:
        raise ValueError(f"dataset at {str(root)!r} has no episodes")
    table = ds.hf_dataset.data
    cols = {}
    for name in PER_EPISODE_COLUMNS:
        width = int(ds.meta.features[name]["shape"][0])
        cols[name] = table.column(name).combine_chunks().flatten().to_numpy().reshape(-1, width)[starts]
    if cols["x_manip"].shape[1] != X_MANIP_DIM:
        raise ValueError(f"dataset at {str(root)!r} has x_manip of length {cols['x_manip'].shape[1]}, "
                         f"the RN expects {X_MANIP_DIM}")
    return Episodes(
        tasks=tuple(str(s["task"]) for s in scenes), texts=tuple(str(t[0]) for t in eps["tasks"]),
        seeds=np.array([int(s["seed"]) for s in scenes], dtype=np.int64),
        scene_params=tuple(dict(s["scene_params"]) for s in scenes),
        x_manip=cols["x_manip"].astype(np.float32), plan=cols["plan"].astype(np.int64),
        label=cols["label"].astype(np.int64), outcomes=tuple(dict(s.get("outcome") or {}) for s in scenes),
        weights=demo_weights(scenes),
    )


def demo_weights(scenes: Sequence[Mapping[str, Any]]) -> np.ndarray:
    """Per episode, the importance weight prior / proposal of its plan (``prl.proposal``), self-normalised to
    mean 1 within each task (each task has its own proposal); 1 for episodes that recorded no log-probabilities
    (a dataset synthesised before proposals existed: its plans came from the prior)."""
    w = np.ones(len(scenes))
    tasks = np.array([str(s["task"]) for s in scenes])
    for task in sorted(set(tasks.tolist())):
        idx = np.nonzero(tasks == task)[0]
        rows = [scenes[i] for i in idx]
        if all(r.get("proposal_logp") is not None and r.get("prior_logp") is not None for r in rows):
            w[idx] = importance_weights([r["prior_logp"] for r in rows], [r["proposal_logp"] for r in rows])
    return w


def point_seed(task: str, seed: int, part: str) -> int:
    """Seed of the surface sampling of one scene's tool or object (stable across runs and processes)."""
    return zlib.crc32(f"{task}/{seed}/{part}".encode())


def point_features(pointnet: Any, tasks: Sequence[str], seeds: Sequence[int],
                   scene_params: Sequence[dict[str, float]], n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """(N, 256) tool and (N, 256) object PointNet features of the scenes' rebuilt meshes."""
    from prl.pointnet import encode_points  # heavy: trimesh
    from prl.shapes import sample_points, scene_meshes

    tool_pts, obj_pts = [], []
    for task, seed, params in zip(tasks, seeds, scene_params, strict=True):
        tool, obj = scene_meshes(task, params)
        tool_pts.append(sample_points(tool, n_points, point_seed(task, int(seed), "tool")))
        obj_pts.append(sample_points(obj, n_points, point_seed(task, int(seed), "object")))
    return encode_points(pointnet, np.stack(tool_pts)), encode_points(pointnet, np.stack(obj_pts))


def assemble(x_manip: np.ndarray, texts: Sequence[str], tool: np.ndarray, obj: np.ndarray) -> np.ndarray:
    """x = [x_manip | TE(text) | tool | object] as (N, 1680) float32, checked against ``FEATURE_LAYOUT``."""
    unique = sorted(set(texts))
    table = dict(zip(unique, embed_texts(unique)))
    te = np.stack([table[t] for t in texts])
    x = np.concatenate([np.asarray(x_manip, np.float32), te, tool, obj], axis=1).astype(np.float32)
    FEATURE_LAYOUT.check(x)
    return x


def episode_features(episodes: Episodes, pointnet: Any, n_points: int) -> np.ndarray:
    """x of every episode of a dataset (see module docstring)."""
    tool, obj = point_features(pointnet, episodes.tasks, episodes.seeds, episodes.scene_params, n_points)
    return assemble(episodes.x_manip, episodes.texts, tool, obj)


def scene_features(task: str, seed: int, scene_params: dict[str, float], x_manip: np.ndarray, text: str,
                   pointnet: Any, n_points: int) -> np.ndarray:
    """x (1, 1680) of one live scene: its observation-phase x_manip, a task sentence and its meshes."""
    tool, obj = point_features(pointnet, [task], [seed], [scene_params], n_points)
    return assemble(np.asarray(x_manip, np.float32)[None], [text], tool, obj)


def split_by_seed(seeds: np.ndarray, val_fraction: float, salt: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(train, val) sorted index arrays, held out by scene: the ``max(1, round(val_fraction * n))``
    scenes whose seed hashes lowest (with ``salt``) form the validation split.

    The split depends only on the seeds, so equal seeds (the same scene) never sit on both sides
    and a re-run splits identically. Raises ValueError when either side would be empty.
    """
    seeds = np.asarray(seeds, dtype=np.int64)
    if not 0.0 < val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in (0, 1), got {val_fraction!r}")
    unique = np.unique(seeds)
    if unique.size < 2:
        raise ValueError(f"cannot hold scenes out: {len(seeds)} episode(s) from {unique.size} scene(s); "
                         f"the RN needs at least 2 scenes")
    rank = np.argsort([zlib.crc32(f"{salt}/{int(s)}".encode()) for s in unique], kind="stable")
    k = max(1, round(val_fraction * unique.size))
    k = min(k, unique.size - 1)
    is_val = np.isin(seeds, unique[rank[:k]])
    return np.nonzero(~is_val)[0], np.nonzero(is_val)[0]
