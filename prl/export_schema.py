"""What a LeRobot v3.0 export of the demonstrations holds (docs/guide/design.md "Export"): names, shapes, files.

One episode per demonstration (``prl.demo.Demo``), one frame per recorded step, the episode's
task being the demo's task sentence. The writer is ``prl.export``, the checks on reload
``prl.export_check``; this module is the contract both follow.

Frame layout (``FEATURES``, the one place where names, shapes and dtypes are declared):

==============================  ===========  =====  ==============================================
feature                         shape        dtype  content
==============================  ===========  =====  ==============================================
observation.state               (60,)        f32    qpos (30) | qvel (30)
observation.environment_state   (52,)        f32    tool, object, mechanism joints, moving bodies (``prl.env_state``)
action                          (30,)        f32    joint targets held over the next 50 Hz step (``replay_actions``)
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

With video (:class:`VideoSpec`), two more features, one per camera of ``VIDEO_CAMERAS``:

==============================  ===========  =====  ==============================================
observation.images.front        (H, W, 3)    video  fixed scene camera (MP4, lerobot's encoder)
observation.images.wrist        (H, W, 3)    video  camera on the palm, looking along the fingers
==============================  ===========  =====  ==============================================

The dataset's fps is the recording rate (``DEFAULT_FPS``, 50): lerobot gives every feature one rate, and
the state stream keeps all its frames. The cameras take ``VideoSpec.fps`` pictures a second; each is held
until the next (the latest picture, as lerobot's recorder reads a camera slower than its loop), so the MP4
files have one frame per dataset frame. See docs/guide/design.md "Dataset video".

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
from prl.env_state import ENV_STATE_DIM, ENV_STATE_NAMES, environment_state

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
    "observation.environment_state": {"dtype": "float32", "shape": (ENV_STATE_DIM,), "names": list(ENV_STATE_NAMES)},
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

VIDEO_CAMERAS: tuple[str, ...] = ("front", "wrist")
"""Cameras of a dataset with video: a fixed scene camera and one on the hand (``envs.video``)."""


def video_key(camera: str) -> str:
    """The feature name of ``camera``'s video (lerobot's convention ``observation.images.<camera>``)."""
    return f"observation.images.{camera}"


@dataclass(frozen=True)
class VideoSpec:
    """Camera video in an export: picture size and how many pictures a second (the rest are held)."""

    width: int = 128
    """Picture width, pixels."""
    height: int = 128
    """Picture height, pixels."""
    fps: int = 10
    """Camera pictures per second, a divisor of the dataset's ``DEFAULT_FPS``; each is held for
    ``DEFAULT_FPS // fps`` dataset frames."""

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 16 <= value <= 4096 or value % 2:
                raise ValueError(f"video {name} must be an even number of pixels in 16..4096, got {value!r}")
        if isinstance(self.fps, bool) or not isinstance(self.fps, int) or self.fps <= 0 or DEFAULT_FPS % self.fps:
            divisors = [d for d in range(1, DEFAULT_FPS + 1) if DEFAULT_FPS % d == 0]
            raise ValueError(f"video fps must divide the dataset's {DEFAULT_FPS} fps (one of {divisors}), "
                             f"got {self.fps!r}")

    @property
    def hold(self) -> int:
        """Dataset frames each camera picture is shown for."""
        return DEFAULT_FPS // self.fps

    def records(self, n_frames: int) -> np.ndarray:
        """The frames (records of the demo) that get a new picture: 0, hold, 2 hold, ..."""
        return np.arange(0, n_frames, self.hold)

    def expand(self, pictures: np.ndarray, n_frames: int) -> np.ndarray:
        """(n_frames, H, W, 3): each of ``pictures`` (taken at :meth:`records`) held until the next."""
        out = np.repeat(np.asarray(pictures), self.hold, axis=0)[:n_frames]
        if out.shape != (n_frames, self.height, self.width, 3) or out.dtype != np.uint8:
            raise ValueError(f"camera pictures expand to {out.shape} {out.dtype}, expected "
                             f"{(n_frames, self.height, self.width, 3)} uint8")
        return out

    def features(self) -> dict[str, dict[str, Any]]:
        """The lerobot feature spec of each camera's video."""
        return {video_key(c): {"dtype": "video", "shape": (self.height, self.width, 3),
                               "names": ["height", "width", "channels"]} for c in VIDEO_CAMERAS}


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
    video_codec: str | None = None
    """The cameras' video codec as ``meta/info.json`` records it (e.g. ``av1``); None without video."""
    video_seconds: float = 0.0
    """Part of ``seconds`` spent rendering the cameras' pictures (the encoding is in lerobot's episode save)."""


def lerobot_features(video: VideoSpec | None = None) -> dict[str, dict[str, Any]]:
    """A fresh copy of ``FEATURES`` (and with ``video`` the cameras' features) for ``LeRobotDataset.create``
    (which must not alias ours)."""
    specs = {**FEATURES, **(video.features() if video is not None else {})}
    return {name: {**spec, "shape": tuple(spec["shape"]),
                   "names": list(spec["names"]) if spec["names"] is not None else None}
            for name, spec in specs.items()}


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
        "observation.environment_state": environment_state(
            arr("tool_pose", (7,)), arr("object_pose", (7,)), _scene_array(demo, "scene_pose", t),
            _scene_array(demo, "scene_qpos", t)),
        "action": replay_actions(arr("target", (N_JOINTS,))),
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


OPTIONAL_FEATURES: tuple[str, ...] = ("observation.environment_state",)
"""Features a dataset exported before they existed lacks: such a dataset still loads and validates, and what needs
one of them says so (``require_feature``)."""


def require_feature(info_features: Any, name: str, root: Path | str) -> None:
    """ValueError naming ``name`` and the dataset ``root`` when the dataset's features (``meta/info.json``'s
    ``features`` or a loaded dataset's ``features``) lack it: a dataset exported before it existed."""
    if name not in info_features:
        raise ValueError(f"the dataset at {str(root)!r} has no {name!r} feature (exported before it existed): "
                         f"export it again from its demos")


def replay_actions(target: np.ndarray) -> np.ndarray:
    """The ``action`` stream of one demo from its recorded joint targets (T, 30), one row per record: row k is the
    executor's target at record k + 1 (the last row keeps its own). Records are 5 physics frames apart, as are the
    steps of a controller at the dataset's rate; the executor moves its targets every frame, and a controller that
    interpolates its commands over each step (``envs.joint_env``) follows the executor's path when each command is
    the target to reach at the step's end, the next record's. Replaying the rows one per step (``envs.replay``)
    thus retraces the recorded states; it is the command sent at that frame in lerobot's sense, for a robot whose
    controller runs at the dataset's fps and interpolates."""
    target = np.asarray(target)
    return np.concatenate([target[1:], target[-1:]], axis=0) if len(target) else target


def _scene_array(demo: Any, name: str, t: int) -> np.ndarray:
    """A demo's ``scene_pose`` or ``scene_qpos`` (``prl.demo.SCENE_ARRAYS``); ValueError naming it when the demo was
    recorded before scenes were (the environment state cannot be built)."""
    a = getattr(demo, name, None)
    if a is None:
        raise ValueError(f"the demo has no {name!r} array (recorded before scene parts were): "
                         f"observation.environment_state cannot be exported from it")
    a = np.asarray(a)
    if a.shape[0] != t:
        raise ValueError(f"array {name!r} has {a.shape[0]} frames, expected {t}")
    return a


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
    values, from which ``prl.shapes`` rebuilds the tool and object meshes), ``outcome``, ``source``,
    ``proposal_logp`` and ``prior_logp`` (the plan's log-probabilities under the synthesis proposal that drew
    it and under the task's prior, ``prl.proposal``; None in a dataset synthesised before they were recorded).
    """
    path = Path(root) / SCENES_FILE
    if not path.is_file():
        raise FileNotFoundError(f"dataset at {str(root)!r} has no scene records ({SCENES_FILE} is missing)")
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    if [r.get("episode_index") for r in rows] != list(range(len(rows))):
        raise ValueError(f"{str(path)!r}: episode_index values are not 0..{len(rows) - 1}")
    return rows
