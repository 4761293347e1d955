"""What a LeRobot v3.0 export of the demonstrations holds (docs/design.md "Export"): names, shapes, files.

One episode per demonstration (``prl.demo.Demo``), one frame per recorded step, the episode's
task being the demo's task sentence. The writer is ``prl.export``, the checks on reload
``prl.export_check``; this module is the contract both follow.

Frame layout (``FEATURES``, the one place where names, shapes and dtypes are declared):

==============================  ===========  =====  ==============================================
feature                         shape        dtype  content
==============================  ===========  =====  ==============================================
observation.state               (60,)        f32    qpos (30) | qvel (30)
action                          (30,)        f32    joint drive targets
observation.contact_force       (17,)        f32    sensor force per patch
observation.contact_position    (51,)        f32    (17, 3) contact points, row-major
observation.contact_normal      (51,)        f32    (17, 3) contact normals, row-major
observation.palm_pose           (7,)         f32    position xyz | quaternion wxyz (SAPIEN order)
observation.tool_pose           (7,)         f32    idem
observation.object_pose         (7,)         f32    idem
stage                           (1,)         i64    executor stage index (``prl.stages.STAGES``)
plan                            (6,)         i64    commanded plan, constant over the episode
label                           (6,)         i64    recovered physical-law label, or -1s
x_manip                         (784,)       f32    observation-phase features (before the plan acts), constant
==============================  ===========  =====  ==============================================

lerobot adds ``timestamp``, ``frame_index``, ``episode_index``, ``index`` and ``task_index``.

Beside lerobot's files, ``SCENES_FILE`` holds one JSON line per episode with its scene
(:func:`read_scenes`) and ``EXPORT_KEY_FILE`` the key of the inputs (``prl.export.export_key``).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prl.constants import JOINT_NAMES, N_JOINTS, N_SENSORS, RECORD_HZ, RS_DIMS, SENSOR_NAMES

CODEBASE_VERSION = "v3.0"
"""LeRobot dataset format written and accepted."""
DEFAULT_REPO_ID = "prl/hammer"
"""Default dataset identifier (only a name: nothing is pushed to the Hub)."""
SCENES_FILE = "meta/prl_scenes.jsonl"
"""Sidecar written next to lerobot's metadata: one JSON line per episode with its scene (see
:func:`read_scenes`); lerobot itself ignores it."""
EXPORT_KEY_FILE = "meta/prl_export_key.txt"
"""The key of the inputs an export was written from (``prl.export.export_key``), for
``prl.export.reusable_export``."""
DEFAULT_FPS = RECORD_HZ
"""Recording rate of the demos (``prl.constants.RECORD_HZ``, the executor's record interval)."""
ROBOT_TYPE = "prl_hand"
"""``robot_type`` written to ``meta/info.json`` (the agent's uid)."""
NO_LABEL = -1
"""Label value of an episode without a recovered physical-law label."""
PLAN_DIM = len(RS_DIMS)
"""Length of plan and label vectors (6)."""

_POSE_NAMES = ["x", "y", "z", "qw", "qx", "qy", "qz"]
_XYZ = ("x", "y", "z")

FEATURES: dict[str, dict[str, Any]] = {
    "observation.state": {
        "dtype": "float32", "shape": (2 * N_JOINTS,),
        "names": [f"{j}.pos" for j in JOINT_NAMES] + [f"{j}.vel" for j in JOINT_NAMES],
    },
    "action": {"dtype": "float32", "shape": (N_JOINTS,), "names": [f"{j}.target" for j in JOINT_NAMES]},
    "observation.contact_force": {"dtype": "float32", "shape": (N_SENSORS,), "names": list(SENSOR_NAMES)},
    "observation.contact_position": {
        "dtype": "float32", "shape": (3 * N_SENSORS,), "names": [f"{s}.{a}" for s in SENSOR_NAMES for a in _XYZ],
    },
    "observation.contact_normal": {
        "dtype": "float32", "shape": (3 * N_SENSORS,), "names": [f"{s}.n{a}" for s in SENSOR_NAMES for a in _XYZ],
    },
    "observation.palm_pose": {"dtype": "float32", "shape": (7,), "names": list(_POSE_NAMES)},
    "observation.tool_pose": {"dtype": "float32", "shape": (7,), "names": list(_POSE_NAMES)},
    "observation.object_pose": {"dtype": "float32", "shape": (7,), "names": list(_POSE_NAMES)},
    "stage": {"dtype": "int64", "shape": (1,), "names": None},
    "plan": {"dtype": "int64", "shape": (PLAN_DIM,), "names": None},
    "label": {"dtype": "int64", "shape": (PLAN_DIM,), "names": None},
    "x_manip": {"dtype": "float32", "shape": (784,), "names": None},
}
"""Every exported feature: lerobot feature spec (dtype, shape, names). The single declaration."""


PER_EPISODE = ("plan", "label", "x_manip")
"""Features constant over an episode."""


class ExportError(RuntimeError):
    """An export or a validation failed; the message says what and where."""


@dataclass(frozen=True)
class ExportReport:
    """Outcome of an export or of a validation of a dataset on disk."""

    root: Path
    """Dataset root (after an export: the destination)."""
    repo_id: str
    """Dataset identifier."""
    fps: int
    """Frames per second in ``meta/info.json``."""
    n_episodes: int
    """Episodes."""
    n_frames: int
    """Frames over all episodes."""
    episode_lengths: tuple[int, ...]
    """Frames per episode, by episode index."""
    tasks: tuple[str, ...]
    """Task sentence per episode, by episode index."""
    n_labelled: int
    """Episodes whose label is not all ``NO_LABEL``."""
    size_bytes: int
    """Bytes of all files under ``root``."""
    seconds: float
    """Wall time of the export (write + validate + move) or of the validation alone."""
    checked_against_demos: bool = False
    """True when episodes were compared with their demos (lengths, tasks, plan, label, a state)."""
    reused: bool = False
    """True when an identical earlier export was found, reloaded and validated instead of rewritten."""


def lerobot_features() -> dict[str, dict[str, Any]]:
    """A fresh copy of ``FEATURES`` for ``LeRobotDataset.create`` (which must not alias ours)."""
    return {name: {**spec, "shape": tuple(spec["shape"]),
                   "names": list(spec["names"]) if spec["names"] is not None else None}
            for name, spec in FEATURES.items()}


def episode_frames(demo: Any, label: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """``{feature: (T, *shape) array}`` of one demo, dtypes as in ``FEATURES`` (raises ValueError)."""
    t = int(np.asarray(demo.stage).shape[0])
    if t == 0:
        raise ValueError("the demo has no recorded frame")

    def arr(name: str, shape: tuple[int, ...]) -> np.ndarray:
        a = np.asarray(getattr(demo, name))
        if a.shape != (t, *shape):
            raise ValueError(f"array {name!r} has shape {a.shape}, expected {(t, *shape)}")
        return a

    plan = np.asarray(demo.plan)
    if plan.shape != (PLAN_DIM,):
        raise ValueError(f"plan has shape {plan.shape}, expected ({PLAN_DIM},)")
    lab = np.full(PLAN_DIM, NO_LABEL, np.int64) if label is None else as_label(label)
    xm = np.asarray(demo.x_manip)
    if xm.shape != FEATURES["x_manip"]["shape"]:
        raise ValueError(f"x_manip has shape {xm.shape}, expected {FEATURES['x_manip']['shape']}")
    out = {
        "observation.state": np.concatenate([arr("qpos", (N_JOINTS,)), arr("qvel", (N_JOINTS,))], axis=1),
        "action": arr("target", (N_JOINTS,)),
        "observation.contact_force": arr("force", (N_SENSORS,)),
        "observation.contact_position": arr("contact_pos", (N_SENSORS, 3)).reshape(t, -1),
        "observation.contact_normal": arr("contact_normal", (N_SENSORS, 3)).reshape(t, -1),
        "observation.palm_pose": arr("palm_pose", (7,)),
        "observation.tool_pose": arr("tool_pose", (7,)),
        "observation.object_pose": arr("object_pose", (7,)),
        "stage": arr("stage", ()).reshape(t, 1),
        "plan": np.broadcast_to(plan, (t, PLAN_DIM)),
        "label": np.broadcast_to(lab, (t, PLAN_DIM)),
        "x_manip": np.broadcast_to(xm, (t, xm.size)),
    }
    assert out.keys() == FEATURES.keys()
    frames = {}
    for name, a in out.items():
        spec = FEATURES[name]
        if spec["dtype"] == "int64" and not np.issubdtype(a.dtype, np.integer):
            raise ValueError(f"feature {name!r} must be integer, got dtype {a.dtype}")
        frames[name] = np.ascontiguousarray(a, dtype=spec["dtype"])
        if not np.all(np.isfinite(frames[name])):
            raise ValueError(f"feature {name!r} holds non-finite values")
    return frames


def as_label(label: Sequence[int] | np.ndarray) -> np.ndarray:
    """``label`` as an int64 (``PLAN_DIM``,) vector; ValueError for a wrong shape or a non-integer value."""
    a = np.asarray(label)
    if a.shape != (PLAN_DIM,):
        raise ValueError(f"label must have shape ({PLAN_DIM},), got {a.shape} ({label!r})")
    if not (np.issubdtype(a.dtype, np.integer) or (np.issubdtype(a.dtype, np.floating) and np.all(a == np.round(a)))):
        raise ValueError(f"label must hold integers, got {label!r}")
    return a.astype(np.int64)


def read_scenes(root: Path | str) -> list[dict[str, Any]]:
    """Per-episode scene records of an exported dataset (``SCENES_FILE``), in episode order.

    Each: ``episode_index``, ``task``, ``seed`` (scene seed), ``scene_params`` (the randomised
    values, from which ``prl.shapes`` rebuilds the tool and object meshes), ``outcome``, ``source``.
    """
    path = Path(root) / SCENES_FILE
    if not path.is_file():
        raise FileNotFoundError(f"dataset at {str(root)!r} has no scene records ({SCENES_FILE} is missing)")
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    if [r.get("episode_index") for r in rows] != list(range(len(rows))):
        raise ValueError(f"{str(path)!r}: episode_index values are not 0..{len(rows) - 1}")
    return rows
