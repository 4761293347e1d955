"""Grasp probe: one reference object per grasp pattern, picked up by the plan executor's grasp stages.

Not one of the paper's tasks (it is not in ``TASK_ENV_IDS`` and never enters the pipeline): it is
the bench on which each catalogue grasp pattern (``assets/plb.yaml`` ``grasp_patterns``) is checked
against the kind of object it is meant for, by contact alone. A pattern's name is a physical law
of this project, so a posture of ``prl.stages.GRASP_POSTURES`` is right only if, closed on its
object and lifting it, it touches the sensors that make ``prl.labels.grasp_label`` return it.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import sapien
import torch
from mani_skill.utils.registration import register_env
from sapien import physx

from envs.tasks.base import DEFAULT_ENV_KWARGS, PRLTaskEnv, pose_from_matrix, pose_to_numpy
from prl.stages import StageSpec

#: Reference objects: kind -> the pattern it is for, the half extents of its box (capsule: half-length,
#: radius, radius; disk: radius, half-height, radius), its mass (kg) and the reference plan that grasps and
#: lifts it (a4 = arm_linear_z: the arm moves further up). Frames follow the hammer handle's convention
#: (T_gv = the whole object; the palm's frame equals the object's frame for a plan with no rotation): local
#: +Y is world up, so the palm comes down onto the object's top. The plate needs the palm tilted by
#: a0 = -30 deg so that the straight fingers lie on its face.
PROBE_OBJECTS: dict[str, dict[str, Any]] = {
    # a hammer-like handle lying along local X on two supports at its ends
    "handle": {"pattern": "medium_wrap", "half": (0.10, 0.016, 0.016), "mass": 0.30, "plan": (0, 3, 2, 0, 4, 1)},
    # a flat box standing on its long edge on a pedestal: thin along local Z
    "plate": {"pattern": "parallel_extension", "half": (0.06, 0.05, 0.0175), "mass": 0.08,
              "plan": (6, 3, 1, 1, 4, 1)},
    # a thin rod (a tweezers' arm) along local X on two supports
    "rod": {"pattern": "palmar_pinch", "half": (0.10, 0.004, 0.006), "mass": 0.04, "plan": (0, 3, 3, 2, 4, 1)},
    # a disk standing on its flat face (a large bottle cap), axis = local Y
    "disk": {"pattern": "precision_disk", "half": (0.036, 0.012, 0.036), "mass": 0.05, "plan": (0, 3, 2, 3, 4, 1)},
}
PROBE_FRICTION = 1.0
"""Static = dynamic friction of the reference objects."""
REST_HEIGHT = 0.09
"""Height (m) of the object's centre above the table at rest (room under it for the fingers)."""
REST_XY = (-0.05, -0.10)
"""World (x, y) of the object's centre at rest (under the hand's home pose)."""
LIFT_SUCCESS_M = 0.04
"""The object counts as picked up when its centre ends this much above its rest height."""
PROBE_ENV_ID = "PRL-GraspProbe-v1"


def make_probe_env(kind: str, **kwargs: Any) -> Any:
    """The grasp probe with reference object ``kind`` (one CPU scene, like ``envs.tasks.make_env``)."""
    return gym.make(PROBE_ENV_ID, **(DEFAULT_ENV_KWARGS | {"render_backend": "cpu"} | kwargs), object_kind=kind)


@register_env(PROBE_ENV_ID, max_episode_steps=150)
class PRLGraspProbeEnv(PRLTaskEnv):
    """**Task Description:**
    The hand grasps one reference object (``object_kind``: handle, plate, rod or disk) and lifts it.
    The object is one dynamic rigid actor held by contact and friction only.

    **Randomizations:**
    - object position +-1 cm in x and y (``randomization`` scales it)

    **Success Conditions:**
    - the object's centre ends more than 4 cm above its rest height
    """

    task_name = "grasp_probe"
    pipeline_task = False
    measure_key = "lift_cm"
    expert_plan = PROBE_OBJECTS["handle"]["plan"]
    stages: ClassVar[StageSpec] = StageSpec(
        shares=(("pregrasp", 0.30), ("approach", 0.15), ("grasp", 0.25), ("lift", 0.20), ("motion", 0.10)),
    )
    """Grasp and lift; the reference plans' motion (arm straight up) lifts the object further."""

    def __init__(self, *args: Any, object_kind: str = "handle", **kwargs: Any) -> None:
        if object_kind not in PROBE_OBJECTS:
            raise ValueError(f"unknown object_kind {object_kind!r}; known: {sorted(PROBE_OBJECTS)}")
        self.object_kind = object_kind
        super().__init__(*args, **kwargs)

    def _load_scene(self, options: dict) -> None:
        rng = self._scene_rng()
        spec = PROBE_OBJECTS[self.object_kind]
        half = np.asarray(spec["half"], dtype=np.float64)
        self.scene_params = {
            "x": REST_XY[0] + self._uniform(rng, -0.01, 0.01),
            "y": REST_XY[1] + self._uniform(rng, -0.01, 0.01),
            "mass": float(spec["mass"]),
        }
        self._build_table()
        material = physx.PhysxMaterial(PROBE_FRICTION, PROBE_FRICTION, 0.0)
        builder = self.scene.create_actor_builder()
        color = sapien.render.RenderMaterial(base_color=[0.3, 0.5, 0.7, 1])
        if self.object_kind == "handle":
            density = spec["mass"] / (np.pi * half[1] ** 2 * 2 * half[0] + 4 / 3 * np.pi * half[1] ** 3)
            builder.add_capsule_collision(radius=half[1], half_length=half[0], material=material, density=density)
            builder.add_capsule_visual(radius=half[1], half_length=half[0], material=color)
        elif self.object_kind == "disk":  # cylinder axis (SAPIEN's X) turned onto local Y
            pose = sapien.Pose(q=[0.7071068, 0.0, 0.0, 0.7071068])
            density = spec["mass"] / (np.pi * half[0] ** 2 * 2 * half[1])
            builder.add_cylinder_collision(pose, radius=half[0], half_length=half[1], material=material,
                                           density=density)
            builder.add_cylinder_visual(pose, radius=half[0], half_length=half[1], material=color)
        else:
            density = spec["mass"] / float(np.prod(2 * half))
            builder.add_box_collision(half_size=list(half), material=material, density=density)
            builder.add_box_visual(half_size=list(half), material=color)
        builder.initial_pose = self._rest_pose()
        self.tool = builder.build_dynamic(name=f"probe_{self.object_kind}")
        self.tool_gv_local = (np.zeros(3), half.copy())
        self.tool_fv_local = (np.zeros(3), half.copy())
        self._build_supports(half)

    def _rest_pose(self) -> sapien.Pose:
        """Local X = world X, local Y = world Z (up), local Z = -world Y."""
        axes = np.column_stack([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
        p = self.scene_params
        return pose_from_matrix(np.array([p["x"], p["y"], REST_HEIGHT]), axes)

    def _build_supports(self, half: np.ndarray) -> None:
        """Static props that hold the object at rest and leave its middle free for the fingers."""
        p = self.scene_params
        grey = (0.3, 0.3, 0.35, 1)
        if self.object_kind in ("handle", "rod"):  # two blocks under the ends
            top = REST_HEIGHT - half[1]
            for i, sx in enumerate((-1.0, 1.0)):
                center = np.array([p["x"] + sx * (half[0] - 0.012), p["y"], top / 2])
                self._build_static_box(f"support{i}", center, np.array([0.012, 0.03, top / 2]), 0.0, grey)
        elif self.object_kind == "plate":  # standing on its long edge on a pedestal as long as it
            bottom = REST_HEIGHT - half[1]
            self._build_static_box("pedestal", np.array([p["x"], p["y"], bottom / 2]),
                                   np.array([half[0], half[2], bottom / 2]), 0.0, grey)
        else:  # disk on a narrow pedestal
            bottom = REST_HEIGHT - half[1]
            self._build_static_box("pedestal", np.array([p["x"], p["y"], bottom / 2]),
                                   np.array([0.012, 0.012, bottom / 2]), 0.0, grey)

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        self.tool.set_pose(self._rest_pose())
        self.tool.set_linear_velocity(torch.zeros((1, 3)))
        self.tool.set_angular_velocity(torch.zeros((1, 3)))
        self._reset_hand()

    def object_frame_world(self) -> tuple[np.ndarray, np.ndarray]:
        """A point 10 cm above the object's rest place, Z up (nothing is brought to it)."""
        p = self.scene_params
        return np.array([p["x"], p["y"], REST_HEIGHT + 0.10]), np.eye(3)

    def evaluate(self) -> dict[str, torch.Tensor]:
        position, _ = pose_to_numpy(self.tool.pose.raw_pose)
        lift = float(position[2] - REST_HEIGHT)
        broken = self.tool_is_broken()
        return {
            "success": torch.tensor([lift > LIFT_SUCCESS_M]) & ~broken,
            "fail": broken,
            "lift_cm": torch.tensor([lift * 100.0]),
        }
