"""``observation.environment_state``: what a state-based policy sees of a task scene besides the hand, in one
fixed layout for every task (lerobot's name for a simulated object's state, as in its PushT and ALOHA datasets).

=====================  =====  ==================================================================================
slice                  size   content
=====================  =====  ==================================================================================
tool.*                 7      the tool's pose: x, y, z, qw, qx, qy, qz (SAPIEN order)
object.*               7      the object frame's pose (the nail, the cap, the debris zone, the cube), idem
joint<j>               2      the scene's mechanism joints in the scene's order (the nail's depth, the cap's
                              turn, the tweezers' opening), 0 where the task has fewer
part<i>.x/.y/.z        9 x 3  the position of each moving body in the scene's order (the hammer or broom again,
                              the sweep's debris, the tweeze cube, the bottle and the tweezers' roots)
part<i>.present        9      1 for a slot that holds a body, 0 for an empty one (its position then reads 0)
=====================  =====  ==================================================================================

The same function builds it from a demo's recorded arrays (the export, ``prl.export_schema``) and from the live
scene (the joint-control environment, ``envs.joint_env``), so a policy trained on a dataset acts in the environment
unchanged. Bodies and joints are those of ``envs.scene_record.SceneParts`` (``prl.demo.SCENE_ARRAYS``).
"""

from __future__ import annotations

import numpy as np

ENV_JOINT_SLOTS = 2
"""Mechanism joints the layout holds (each task has one)."""
ENV_PART_SLOTS = 9
"""Moving bodies the layout holds (the sweep's broom and its most debris cubes)."""

_POSE = ("x", "y", "z", "qw", "qx", "qy", "qz")

ENV_STATE_NAMES: tuple[str, ...] = (
    *(f"tool.{a}" for a in _POSE), *(f"object.{a}" for a in _POSE),
    *(f"joint{j}" for j in range(ENV_JOINT_SLOTS)),
    *(f"part{i}.{a}" for i in range(ENV_PART_SLOTS) for a in ("x", "y", "z")),
    *(f"part{i}.present" for i in range(ENV_PART_SLOTS)),
)
"""The names of ``environment_state``'s values, in order."""
ENV_STATE_DIM = len(ENV_STATE_NAMES)
"""Values of ``environment_state`` (52)."""


def environment_state(tool_pose: np.ndarray, object_pose: np.ndarray, body_poses: np.ndarray,
                      joint_qpos: np.ndarray) -> np.ndarray:
    """(T, ``ENV_STATE_DIM``) float32 environment states of T frames (or (``ENV_STATE_DIM``,) for one frame given
    unbatched): ``tool_pose`` and ``object_pose`` (T, 7), ``body_poses`` (T, B, 7) of the scene's B moving bodies
    and ``joint_qpos`` (T, J) of its mechanism joints.
    ValueError naming the count when a scene has more joints or bodies than the layout's slots, or a bad shape."""
    single = np.ndim(tool_pose) == 1
    tool, obj = np.atleast_2d(tool_pose), np.atleast_2d(object_pose)
    poses = np.asarray(body_poses, np.float64)
    poses = poses[None] if single else poses
    qpos = np.asarray(joint_qpos, np.float64)
    qpos = qpos.reshape(1, -1) if single else qpos.reshape(len(tool), -1)
    t = tool.shape[0]
    if tool.shape != (t, 7) or obj.shape != (t, 7) or poses.ndim != 3 or poses.shape[::2] != (t, 7):
        raise ValueError(f"environment_state needs (T, 7) tool and object poses and (T, B, 7) body poses, "
                         f"got {tool.shape}, {obj.shape} and {poses.shape}")
    n_bodies = poses.shape[1]
    if n_bodies > ENV_PART_SLOTS or qpos.shape[1] > ENV_JOINT_SLOTS:
        raise ValueError(f"a scene of {n_bodies} moving bodies and {qpos.shape[1]} joints does not fit "
                         f"environment_state's {ENV_PART_SLOTS} body and {ENV_JOINT_SLOTS} joint slots")
    joints = np.zeros((t, ENV_JOINT_SLOTS))
    joints[:, :qpos.shape[1]] = qpos
    parts = np.zeros((t, ENV_PART_SLOTS, 3))
    parts[:, :n_bodies] = poses[:, :, :3]
    present = np.zeros((t, ENV_PART_SLOTS))
    present[:, :n_bodies] = 1.0
    out = np.concatenate([tool, obj, joints, parts.reshape(t, -1), present], axis=1).astype(np.float32)
    return out[0] if single else out
