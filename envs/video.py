"""Camera pictures of a recorded plan episode, rendered by replaying the demo kinematically (no physics).

Two cameras (``prl.export_schema.VIDEO_CAMERAS``): ``front``, fixed on the workspace (``FRONT_VIEW``), and ``wrist``, mounted on the palm link and looking
along the fingers at what the hand holds, so it moves with the hand.

A demo is replayed by resetting its task with the demo's seed, which rebuilds the same randomised scene
(checked against the demo's ``scene_params``), then, for each record to show, putting the hand's joint
positions (``qpos``) and every other body that moves (``envs.scene_record``: the demo's ``scene_*``
arrays) where the demo recorded them, and rendering. Nothing is stepped, so a replay costs one reset and
the pictures, and only the demos that are kept are ever rendered. ``tests/envs/test_video.py`` checks that a
replayed picture matches the one taken live at the same instant of the episode.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import ExitStack
from typing import Any, Self

import numpy as np

from envs.render_probe import require_rendering
from envs.render_stages import View, add_camera, look_at, take_picture
from envs.scene_record import SceneParts
from envs.tasks import fast_resets, make_env
from prl.demo import SCENE_ARRAYS, Demo, require_arrays
from prl.export_schema import VIDEO_CAMERAS, VideoSpec

FRONT_VIEW = View(eye=(0.42, -0.66, 0.52), target=(0.0, 0.0, 0.1), fovy_deg=48.0)
"""The fixed scene camera: the stage pictures' workspace view (``envs.render_stages.VIEWS``) from further back,
so that a square picture holds every task's tool, object and the hand's path between them."""
WRIST_EYE = (0.0, -0.075, -0.035)
"""Wrist camera position in the palm frame (+Z along the fingers, -Y out of the palm's front face): in front
of the palm, behind the wrist."""
WRIST_TARGET = (0.0, -0.01, 0.13)
"""The point of the palm frame the wrist camera looks at: between the half-closed fingers."""
WRIST_FOVY_DEG = 75.0
"""Vertical field of view of the wrist camera (wide: the tool is a few cm away)."""


def add_video_cameras(env: Any, width: int, height: int) -> dict[str, Any]:
    """The two cameras, added to ``env``'s current scene (after a reset: the scene is rebuilt on every one)."""
    env = env.unwrapped if hasattr(env, "unwrapped") else env
    front = add_camera(env, FRONT_VIEW, (width, height), name="video_front")
    palm = env.agent.palm_link._objs[0].entity
    wrist = env.scene.sub_scenes[0].add_mounted_camera(
        "video_wrist", palm, look_at(np.array(WRIST_EYE), np.array(WRIST_TARGET), up=(0.0, 1.0, 0.0)),
        int(width), int(height), float(np.deg2rad(WRIST_FOVY_DEG)), 0.005, 10.0)
    cameras = {"front": front, "wrist": wrist}
    assert tuple(cameras) == VIDEO_CAMERAS
    return cameras


def pictures(env: Any, cameras: dict[str, Any]) -> dict[str, np.ndarray]:
    """One (H, W, 3) uint8 picture per camera of the scene as it is now."""
    return {name: take_picture(env, camera) for name, camera in cameras.items()}


def set_recorded_state(env: Any, parts: SceneParts, demo: Demo, k: int) -> None:
    """Put the hand and every other moving body where ``demo`` recorded them at record ``k`` (no physics step)."""
    env = env.unwrapped if hasattr(env, "unwrapped") else env
    agent = env.agent
    full = np.empty(len(agent.joint_perm), dtype=np.float32)
    full[agent.joint_perm] = np.asarray(demo.qpos[k], dtype=np.float32)
    agent.robot._objs[0].set_qpos(full)
    parts.set(demo.scene_pose[k], demo.scene_qpos[k])


class DemoRenderer:
    """Renders demos' records with the two cameras at ``spec``'s size; use as a context manager (one env per task,
    closed on exit).

    ``renderer(demo, records)`` returns ``{camera: (len(records), H, W, 3) uint8}``; the signature the LeRobot
    export takes (``prl.export.export_lerobot``'s ``render_images``)."""

    def __init__(self, spec: VideoSpec) -> None:
        self.width, self.height = spec.width, spec.height
        self._envs: dict[str, Any] = {}
        self._stack = ExitStack()

    def __enter__(self) -> Self:
        require_rendering("dataset video (pass --no-video to export without it)")
        self._stack.enter_context(fast_resets())
        return self

    def __exit__(self, *exc: object) -> None:
        for gym_env in self._envs.values():
            gym_env.close()
        self._envs.clear()
        self._stack.close()

    def __call__(self, demo: Demo, records: Sequence[int], source: str = "") -> dict[str, np.ndarray]:
        require_arrays(demo, ("qpos", *SCENE_ARRAYS), "to render its video", source)
        records = [int(k) for k in records]
        n = len(demo.qpos)
        if any(k < 0 or k >= n for k in records):
            raise ValueError(f"records {records} are outside the demo's 0..{n - 1}")
        if demo.task not in self._envs:
            self._envs[demo.task] = make_env(demo.task)
        env = self._envs[demo.task].unwrapped
        env.reset(seed=int(demo.seed))
        check_same_scene(env.scene_params, demo, source)
        parts = SceneParts(env)
        if parts.bodies != tuple(demo.scene_bodies) or parts.joints != tuple(demo.scene_joints):
            raise ValueError(f"{source or 'the demo'}: the rebuilt scene's moving parts {parts.bodies} / "
                             f"{parts.joints} differ from the recorded {tuple(demo.scene_bodies)} / "
                             f"{tuple(demo.scene_joints)}")
        cameras = add_video_cameras(env, self.width, self.height)
        out = {name: np.empty((len(records), self.height, self.width, 3), np.uint8) for name in cameras}
        for i, k in enumerate(records):
            set_recorded_state(env, parts, demo, k)
            for name, image in pictures(env, cameras).items():
                out[name][i] = image
        return out


def check_same_scene(params: dict[str, float], demo: Demo, source: str = "") -> None:
    """ValueError naming the first randomised value that differs between the rebuilt scene and the demo's."""
    keys = sorted(set(params) | set(demo.scene_params))
    for key in keys:
        a, b = params.get(key), demo.scene_params.get(key)
        if a is None or b is None or not np.isclose(float(a), float(b), rtol=0.0, atol=1e-9):
            raise ValueError(f"{source or 'the demo'}: the scene rebuilt from seed {demo.seed} has {key}={a}, the "
                             f"demo {b}: the task's scene code changed since the demo was recorded")
