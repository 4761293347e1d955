"""Every body of a task scene that moves besides the hand: read at each recorded frame, set back for a replay.

A plan episode (``envs.episode``) records, at every recorded frame, the pose of every non-static actor
(the tool, the sweep's debris cubes, the tweeze cube) and the root pose and joint positions of every
articulation other than the hand (the hammer's nail, the bottle and its cap, the tweezers and their
hinge). The parts are found from the scene itself (ManiSkill's ``scene.actors`` and
``scene.articulations``), so no task is named here. With the hand's joint positions (recorded as
``qpos``) that is every body that moves, so a demo can be shown again by putting them back without
stepping the physics (``envs.video``): the static props are rebuilt by the reset with the demo's seed.

Layout (``prl.demo.SCENE_ARRAYS``): the bodies are
the actors in the scene's order, then the articulations' roots under the articulation's name; the joints
are ``<articulation>/<joint>`` for each articulation's active joints, in its order.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import sapien


def sapien_pose7(pose: Any) -> np.ndarray:
    """A SAPIEN pose as [x, y, z, qw, qx, qy, qz] (float64), the layout of every recorded pose."""
    return np.concatenate([np.asarray(pose.p, dtype=np.float64), np.asarray(pose.q, dtype=np.float64)])


class SceneParts:
    """The moving parts of ``env``'s current scene (rebuilt on every reset: make one per episode)."""

    def __init__(self, env: Any) -> None:
        env = env.unwrapped if hasattr(env, "unwrapped") else env
        scene = env.scene
        hand = env.agent.robot if env.agent is not None else None
        self._actors = [(name, actor._objs[0]) for name, actor in scene.actors.items()
                        if actor.px_body_type != "static"]
        self._articulations = [(name, art._objs[0]) for name, art in scene.articulations.items() if art is not hand]
        self.bodies: tuple[str, ...] = tuple(name for name, _ in self._actors) + tuple(
            name for name, _ in self._articulations)
        """Body names: the non-static actors, then the articulations (their roots)."""
        joints = []
        self._dofs = []
        for name, px in self._articulations:
            active = px.get_active_joints()
            self._dofs.append(len(active))
            joints += [f"{name}/{_joint_name(name, j.name)}" for j in active]
        self.joints: tuple[str, ...] = tuple(joints)
        """Joint names ``<articulation>/<joint>`` of the non-hand articulations."""

    def poses(self) -> np.ndarray:
        """(bodies, 7) poses [x, y, z, qw, qx, qy, qz] now."""
        out = np.empty((len(self.bodies), 7))
        for i, (_, entity) in enumerate(self._actors):
            out[i] = sapien_pose7(entity.get_pose())
        for i, (_, px) in enumerate(self._articulations, start=len(self._actors)):
            out[i] = sapien_pose7(px.get_root_pose())
        return out

    def qpos(self) -> np.ndarray:
        """(joints,) joint positions now."""
        parts = [np.asarray(px.get_qpos(), dtype=np.float64) for _, px in self._articulations]
        return np.concatenate(parts) if parts else np.zeros(0)

    def set(self, poses: np.ndarray, qpos: np.ndarray) -> None:
        """Put every part where ``poses`` / ``qpos`` (one recorded frame) say, without stepping the physics."""
        poses, qpos = np.asarray(poses, dtype=np.float64), np.asarray(qpos, dtype=np.float64)
        if poses.shape != (len(self.bodies), 7) or qpos.shape != (len(self.joints),):
            raise ValueError(f"a frame of {len(self.bodies)} body poses and {len(self.joints)} joint positions "
                             f"was expected, got shapes {poses.shape} and {qpos.shape}")
        for i, (_, entity) in enumerate(self._actors):
            entity.set_pose(sapien.Pose(poses[i, :3], poses[i, 3:]))
        start = 0
        for i, ((_, px), dof) in enumerate(zip(self._articulations, self._dofs, strict=True), start=len(self._actors)):
            px.set_root_pose(sapien.Pose(poses[i, :3], poses[i, 3:]))
            px.set_qpos(qpos[start:start + dof].astype(np.float32))
            start += dof


def _joint_name(articulation: str, sapien_name: str) -> str:
    """``nail_joint`` of the SAPIEN joint name ``scene-0-nail_nail_joint`` (ManiSkill prefixes scene and owner)."""
    prefix = f"{articulation}_"
    tail = sapien_name.split("-", 2)[-1] if sapien_name.startswith("scene-") else sapien_name
    return tail.removeprefix(prefix)
