"""One demonstration on disk: an executed plan with its scene, trajectory and x_manip.

A :class:`Demo` is what scene synthesis keeps and what label recovery and dataset export
read. It is saved as one ``.npz`` (arrays) with a JSON header (scalars, dicts), written to a
temporary name and renamed, so a killed writer never leaves a half-written demo.

x_manip (the paper's "manipulation demonstration data from the initial phase", Eq 2) is
defined here as ``X_MANIP_SAMPLES`` = 8 evenly spaced states of the observation phase that
precedes every plan (``envs.executor.PlanExecutor.observe``: the hand holds its home pose for
``ExecutorConfig.observe_frames`` physics frames while the tool and object settle). It is taken
before the plan acts on purpose: the pre-grasp already depends on the plan's a0-a2, so features
from it would give the answer away to the Representation Network, and they would not exist for
a new scene whose plan the network is asked to choose. Each sample is

    qpos (30) | qvel (30) | sensor force (17) | palm pose (7) | tool pose (7) | object pose (7)

= 98 values per sample, 784 in all (the paper's is 786-d).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prl.atomic import atomic_file
from prl.constants import N_JOINTS, N_SENSORS

X_MANIP_SAMPLES = 8
"""Samples of the observation phase in x_manip."""
X_MANIP_LAYOUT: tuple[tuple[str, int], ...] = (
    ("qpos", N_JOINTS), ("qvel", N_JOINTS), ("force", N_SENSORS),
    ("palm_pose", 7), ("tool_pose", 7), ("object_pose", 7),
)
"""(field, width) of one x_manip sample, in order."""
X_MANIP_DIM = X_MANIP_SAMPLES * sum(w for _, w in X_MANIP_LAYOUT)
"""Length of x_manip (784)."""

SCENE_ARRAYS: tuple[str, ...] = ("scene_bodies", "scene_pose", "scene_joints", "scene_qpos")
"""Every other body that moves, per record (``envs.scene_record``): ``scene_bodies`` (B,) names (the
non-static actors, then the non-hand articulations' roots), ``scene_pose`` (T, B, 7), ``scene_joints`` (J,)
names ``<articulation>/<joint>``, ``scene_qpos`` (T, J). With ``qpos`` they let a demo be rendered again
without physics (``envs.video``). Demo files written before 2026-12-02 lack them: they still load, and
what needs them names the missing arrays (:func:`require_arrays`)."""

ARRAY_FIELDS: tuple[str, ...] = (
    "plan", "frame", "stage", "qpos", "qvel", "target", "force", "contact_pos", "contact_normal",
    "palm_pose", "tool_pose", "object_pose", "anchors_at_grasp", "gv_center", "gv_half", "gv_rot",
    "tool_gv_local", "tool_fv_local", "x_manip", *SCENE_ARRAYS,
)


@dataclass
class Demo:
    """An executed plan: identity, outcome and recorded arrays (see ``envs.execution.EpisodeResult``)."""

    task: str
    """Task name."""
    seed: int
    """Scene seed (domain randomisation)."""
    text: str
    """The task sentence of this episode."""
    success: bool
    """Success measured in simulation."""
    outcome: dict[str, Any]
    """The task's ``evaluate()`` at the end (plain values)."""
    scene_params: dict[str, float]
    """The randomised scene values."""
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    """Recorded arrays, keys ``ARRAY_FIELDS``."""
    proposal_logp: float | None = None
    """log-probability of the plan under the synthesis proposal that drew it (``prl.proposal``; None: not recorded)."""
    prior_logp: float | None = None
    """log-probability of the plan under the task's prior (the importance weight is exp(prior - proposal))."""

    def __getattr__(self, name: str) -> np.ndarray:
        arrays = self.__dict__.get("arrays", {})
        if name in arrays:
            return arrays[name]
        raise AttributeError(name)


def x_manip_from_samples(samples: dict[str, np.ndarray]) -> np.ndarray:
    """The (784,) x_manip from ``X_MANIP_SAMPLES`` states per ``X_MANIP_LAYOUT`` field (see module docstring)."""
    parts = []
    for name, width in X_MANIP_LAYOUT:
        value = np.asarray(samples[name], dtype=np.float64).reshape(len(samples[name]), -1)
        if value.shape != (X_MANIP_SAMPLES, width):
            raise ValueError(f"x_manip field {name!r} has shape {value.shape}, expected ({X_MANIP_SAMPLES}, {width})")
        parts.append(value)
    return np.concatenate(parts, axis=1).reshape(-1).astype(np.float32)


def from_episode(task: str, seed: int, text: str, result: Any, env: Any, proposal_logp: float | None = None,
                 prior_logp: float | None = None) -> Demo:
    """Build a :class:`Demo` from an ``EpisodeResult`` and the env it ran in (for the scene)."""
    env = env.unwrapped if hasattr(env, "unwrapped") else env
    gv_center, gv_half, gv_rot = result.gv_at_grasp
    arrays = {
        "plan": np.asarray(result.plan, dtype=np.int64),
        **{name: np.asarray(getattr(result, name)) for name in (
            "frame", "stage", "qpos", "qvel", "target", "force", "contact_pos", "contact_normal",
            "palm_pose", "tool_pose", "object_pose", "anchors_at_grasp")},
        "gv_center": np.asarray(gv_center), "gv_half": np.asarray(gv_half), "gv_rot": np.asarray(gv_rot),
        "tool_gv_local": np.concatenate([np.asarray(x, dtype=np.float64) for x in env.tool_gv_local]),
        "tool_fv_local": np.concatenate([np.asarray(x, dtype=np.float64) for x in env.tool_fv_local]),
    }
    arrays["x_manip"] = np.asarray(result.x_manip, dtype=np.float32)
    arrays["scene_bodies"] = np.asarray(result.scene_bodies, dtype=np.str_).reshape(-1)
    arrays["scene_pose"] = np.asarray(result.scene_pose, dtype=np.float64)
    arrays["scene_joints"] = np.asarray(result.scene_joints, dtype=np.str_).reshape(-1)
    arrays["scene_qpos"] = np.asarray(result.scene_qpos, dtype=np.float64)
    return Demo(task=task, seed=int(seed), text=text, success=bool(result.success),
                outcome=dict(result.outcome), scene_params={k: float(v) for k, v in env.scene_params.items()},
                arrays=arrays, proposal_logp=proposal_logp, prior_logp=prior_logp)


def save_demo(demo: Demo, path: Path) -> Path:
    """Write ``demo`` to ``path`` (.npz) atomically (``prl.atomic.atomic_file``: temporary file + rename)."""
    path = Path(path)
    header = {"task": demo.task, "seed": demo.seed, "text": demo.text, "success": demo.success,
              "outcome": demo.outcome, "scene_params": demo.scene_params,
              **{k: v for k, v in (("proposal_logp", demo.proposal_logp), ("prior_logp", demo.prior_logp))
                 if v is not None}}
    with atomic_file(path, "wb") as fh:
        np.savez_compressed(fh, header=np.frombuffer(json.dumps(header).encode(), dtype=np.uint8), **demo.arrays)
    return path


def load_demo(path: Path) -> Demo:
    """Read a demo written by :func:`save_demo`; a clear error names a missing or broken file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"demo file {str(path)!r} does not exist")
    try:
        with np.load(path) as data:
            header = json.loads(bytes(data["header"]).decode())
            arrays = {name: data[name] for name in data.files if name != "header"}
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"demo file {str(path)!r} is unreadable: {exc}") from exc
    missing = [name for name in ("plan", "stage") if name not in arrays]  # consumers name any other gap
    if missing:
        raise ValueError(f"demo file {str(path)!r} lacks arrays {missing}")
    return Demo(task=header["task"], seed=int(header["seed"]), text=header["text"], success=bool(header["success"]),
                outcome=header["outcome"], scene_params=header["scene_params"], arrays=arrays,
                proposal_logp=header.get("proposal_logp"), prior_logp=header.get("prior_logp"))


def require_arrays(demo: Demo, names: tuple[str, ...], why: str, source: str | Path = "") -> None:
    """ValueError naming the arrays of ``names`` that ``demo`` lacks (e.g. a file written before they were
    recorded), what needs them (``why``) and the file (``source``)."""
    missing = [name for name in names if name not in demo.arrays]
    if missing:
        where = f"demo file {str(source)!r}" if source else f"the demo of {demo.task} seed {demo.seed}"
        raise ValueError(f"{where} lacks arrays {missing}, needed {why}; it was recorded before they were "
                         f"(2026-12-02): synthesise it again")
