"""PRL unscrewing task (paper Sec. V-A): grip a bottle cap and turn it open."""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np
import sapien
import torch
from mani_skill.utils.registration import register_env
from mani_skill.utils.structs import Articulation, Link
from sapien import physx

from envs.reach import HandReach
from envs.tasks.base import PRLTaskEnv, pose_from_matrix
from prl.shapes import (  # the cap on a narrow neck, its top 1 mm proud
    CAP_CENTER_HEIGHT,
    CAP_TOP_PROUD,
    NECK_RADIUS,
    unscrew_object_mesh,
    unscrew_tool_mesh,
)
from prl.stages import StageSpec

# --- nominal geometry (metres) -----------------------------------------------------------------------
CAP_RADIUS_RANGE = (0.032, 0.038)
"""Radius of the cap (a wide screw cap: a precision disk spans it)."""
CAP_HALF_HEIGHT_RANGE = (0.010, 0.013)
CAP_MASS = 0.04
CAP_FRICTION_RANGE = (0.9, 1.4)
"""Static = dynamic friction of the cap's knurled side."""
CAP_TOP_FRICTION = 0.05
"""Friction of the cap's smooth top: a palm that only presses on it and turns cannot beat the breakaway torque."""
BREAKAWAY_TORQUE_RANGE = (0.9, 1.5)
"""Torque (N m) the cap's thread holds before it turns, whatever the squeeze (a velocity drive with a force limit)."""
THREAD_DAMPING = 1e4
"""Damping (N m s/rad) of the thread's zero-velocity drive: below the breakaway torque the cap creeps < 1e-5 rad/s."""
BODY_RADIUS_RANGE = (0.022, 0.028)
BODY_HEIGHT_RANGE = (0.035, 0.045)
BOTTLE_XY = (-0.05, -0.10)
"""Nominal world (x, y) of the bottle's axis (under the hand's home pose)."""
BOTTLE_XY_RANGE = 0.02
SUCCESS_DEG = 8.0
"""Success: the cap turned more than this many degrees counter-clockwise seen from above (paper: theta > 8)."""
GRIP_LINKS = 2
"""...and at the end at least this many hand links other than the palm press on the cap's knurled side."""
Z_TO_X_Q = [0.7071068, 0.0, -0.7071068, 0.0]
"""Rotation about Y by -90 deg: maps the joint's X axis onto world +Z (qpos > 0 = counter-clockwise from above)."""
X_TO_Y_Q = [0.7071068, 0.0, 0.0, 0.7071068]
"""Rotation about Z by +90 deg."""
JOINT_IN_CAP = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""The joint frame in the cap's frame: its X (the axis) is the cap's Y, so that at qpos 0 the cap's frame is
the hammer's resting frame (X = world X, Y = up, Z = -world Y) and the hand meets it from above unrotated."""


@register_env("PRL-Unscrew-v1", max_episode_steps=150)
class PRLUnscrewEnv(PRLTaskEnv):
    """**Task Description:**
    The 30-DoF hand grips a bottle's cap from above and turns it open. The bottle stands in a fixed holder: a
    fixed-base articulation (the holder is the root link, so one hand can turn the cap with no second hand on
    the bottle) whose child link, the cap, turns on a ``revolute_unwrapped`` joint about the bottle's axis. The
    thread is a zero-stiffness velocity drive with a force limit: it holds up to a breakaway torque and then
    lets the cap turn, however hard the hand squeezes (PhysX joint friction would scale with the squeeze,
    docs/guide/design.md "Mechanisms as drives"). The cap's side is knurled (friction 0.9-1.4); its top is a smooth disc (friction 0.05)
    standing 1 mm proud, so a palm that only presses on the top and turns does not open it.

    The RS reads here: the tool is the cap (T_gv = the cap's side, where the fingers grip; T_fv = the cap as
    it meets the bottle, its bottom face); the object is the bottle (frame: the cap's seat on the neck, Z along
    the axis, up). The cap's frame has local Y along the bottle axis (up), like the hammer's resting frame, so
    the hand comes down onto it. There is no lift, transport or place: the cap stays on its bottle, so a5
    (which T_fv axis the object's Z is aligned with) is not acted on and reads "Y" whatever the plan; the
    motion acts from the grasp: the arm rotates about the palm (a4 = arm_rotate_palm) and turns the cap.

    **Randomizations:**
    - cap radius in [3.2, 3.8] cm, half-height in [1.0, 1.3] cm, side friction in [0.9, 1.4]
    - breakaway torque in [0.9, 1.5] N m (real screw caps open at about 1-2 N m)
    - bottle body radius in [2.2, 2.8] cm and height in [3.5, 4.5] cm; bottle position +-2 cm in x, y

    **Success Conditions:**
    - the cap turned more than 8 deg counter-clockwise seen from above **during the plan's motion** (read from
      the unwrapped joint position: its change from the first frame of the executor's motion stage to the end;
      a clockwise turn is not success), and at the end at least two hand links other than the palm press on the
      cap's side (``gripped``: a palm that turned it by rubbing its top does not count); reward = that turn in
      degrees. Closing a grasp is not unscrewing: a medium wrap's fingers curl one way round the cap and turn
      it 1-10 deg as they close (seeds 0-7: 1.3-9.7 deg), which counted as opening it until 2026-12-02; that
      turn is ``grasp_turn_deg``, the joint's whole turn ``cap_angle_deg``. A controller without stages (joint
      control) is measured from the reset.
    - fail: NaN in the simulation
    """

    task_name = "unscrew"
    measure_key = "cap_turn_deg"
    measure_unit = "degrees"
    tool_mesh = staticmethod(unscrew_tool_mesh)
    object_mesh = staticmethod(unscrew_object_mesh)
    evidence = ("cap_turn_deg", "grasp_turn_deg", "cap_angle_deg", "gripped")
    expert_plan = (0, 3, 2, 3, 5, 1)
    """No tilt, no twist, anchor 2, precision disk round the cap, arm rotation about the palm, object Z || T_fv Y."""
    unacted_dims = ("tool_object_rot",)
    stages = StageSpec(
        shares=(("pregrasp", 0.25), ("approach", 0.12), ("grasp", 0.23), ("motion", 0.40)),
        fv_approach=(0.0, 0.0, 1.0),
        motion_s=0.8,
    )
    """Grip the cap where it is and turn it (no lift, no transport: the motion starts from the grasp)."""
    bottle: Articulation
    cap: Link

    # ------------------------------------------------------------------ scene
    def _load_scene(self, options: dict) -> None:
        rng = self._scene_rng()
        u = partial(self._uniform, rng)
        self.scene_params = params = {
            "cap_radius": u(*CAP_RADIUS_RANGE),
            "cap_half_height": u(*CAP_HALF_HEIGHT_RANGE),
            "cap_friction": u(*CAP_FRICTION_RANGE),
            "breakaway_torque": u(*BREAKAWAY_TORQUE_RANGE),
            "body_radius": u(*BODY_RADIUS_RANGE),
            "body_height": u(*BODY_HEIGHT_RANGE),
            "bottle_x": BOTTLE_XY[0] + u(-BOTTLE_XY_RANGE, BOTTLE_XY_RANGE),
            "bottle_y": BOTTLE_XY[1] + u(-BOTTLE_XY_RANGE, BOTTLE_XY_RANGE),
        }
        self._build_table()
        self._build_bottle(params)
        self._motion_start_deg = 0.0  # also before the first episode (ManiSkill reads the state at construction)

    def _seat_height(self) -> float:
        """Height of the cap's bottom face (its seat on the neck)."""
        return CAP_CENTER_HEIGHT - self.scene_params["cap_half_height"]

    def _build_bottle(self, params: dict[str, float]) -> None:
        builder = self.scene.create_articulation_builder()
        holder = builder.create_link_builder()
        holder.set_name("bottle")
        glass = sapien.render.RenderMaterial(base_color=[0.35, 0.6, 0.45, 1])
        material = physx.PhysxMaterial(0.8, 0.8, 0.0)
        up = sapien.Pose(q=[0.7071068, 0.0, -0.7071068, 0.0])  # SAPIEN cylinders lie along X; turn X onto Z
        body_h, seat = params["body_height"], self._seat_height()
        body = sapien.Pose(p=[0, 0, body_h / 2], q=up.q)
        holder.add_cylinder_collision(body, radius=params["body_radius"], half_length=body_h / 2, material=material)
        holder.add_cylinder_visual(body, radius=params["body_radius"], half_length=body_h / 2, material=glass)
        neck_half = (seat - body_h) / 2 + 0.002  # into the body and 2 mm into the cap's seat: no coplanar faces
        neck = sapien.Pose(p=[0, 0, body_h + (seat - body_h) / 2], q=up.q)
        holder.add_cylinder_collision(neck, radius=NECK_RADIUS, half_length=neck_half, material=material)
        holder.add_cylinder_visual(neck, radius=NECK_RADIUS, half_length=neck_half, material=glass)

        cap = builder.create_link_builder(holder)
        cap.set_name("cap")
        r, hh = params["cap_radius"], params["cap_half_height"]
        side = physx.PhysxMaterial(params["cap_friction"], params["cap_friction"], 0.0)
        top = physx.PhysxMaterial(CAP_TOP_FRICTION, CAP_TOP_FRICTION, 0.0)
        along_y = sapien.Pose(q=X_TO_Y_Q)  # in the cap's frame the bottle axis is local Y
        cap.add_cylinder_collision(along_y, radius=r, half_length=hh, material=side,
                                   density=CAP_MASS / (np.pi * r**2 * 2 * hh))
        red = sapien.render.RenderMaterial(base_color=[0.75, 0.2, 0.2, 1])
        cap.add_cylinder_visual(along_y, radius=r, half_length=hh, material=red)
        disc = sapien.Pose(p=[0, hh + CAP_TOP_PROUD / 2 - 0.0005, 0], q=X_TO_Y_Q)  # overlaps the cap by 0.5 mm
        cap.add_cylinder_collision(disc, radius=r - 0.003, half_length=CAP_TOP_PROUD / 2 + 0.0005, material=top,
                                   density=100.0)
        cap.add_cylinder_visual(disc, radius=r - 0.003, half_length=CAP_TOP_PROUD / 2 + 0.0005,
                                material=sapien.render.RenderMaterial(base_color=[0.9, 0.9, 0.9, 1]))
        # the joint axis (the joint frame's X) is the bottle axis: world +Z in the holder, local Y in the cap
        cap.set_joint_properties(
            "revolute_unwrapped", limits=[[-np.inf, np.inf]],
            pose_in_parent=sapien.Pose(p=[0, 0, CAP_CENTER_HEIGHT], q=Z_TO_X_Q),
            pose_in_child=pose_from_matrix(np.zeros(3), JOINT_IN_CAP),
        )
        cap.set_joint_name("cap_joint")
        builder.initial_pose = sapien.Pose(p=[params["bottle_x"], params["bottle_y"], 0.0])
        self.bottle = builder.build(name="bottle", fix_root_link=True)
        self.cap = self.bottle.links_map["cap"]
        self.cap_joint = self.bottle.active_joints[0]
        self.cap_joint._objs[0].set_friction(0.0)
        self.cap_joint.set_drive_properties(0.0, THREAD_DAMPING, params["breakaway_torque"])
        self.cap_joint.set_drive_velocity_target(torch.zeros(1))
        self.tool = self.cap
        self.tool_gv_local = (np.zeros(3), np.array([r, hh, r]))
        self.tool_fv_local = (np.array([0.0, -hh, 0.0]), np.array([r, 0.001, r]))

    # ------------------------------------------------------------------ episode
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        self.bottle.set_qpos(torch.zeros((1, 1)))
        self.bottle.set_qvel(torch.zeros((1, 1)))
        self._motion_start_deg = 0.0  # the cap's angle when the plan's motion started (on_stage_start)
        self._reset_hand()

    # ------------------------------------------------------------------ executor API
    def object_frame_world(self) -> tuple[np.ndarray, np.ndarray]:
        """The bottle's frame: origin at the cap's seat on the neck, Z along the bottle axis (up)."""
        p = self.scene_params
        return np.array([p["bottle_x"], p["bottle_y"], self._seat_height()]), np.eye(3)

    def cap_angle_deg(self) -> torch.Tensor:
        """(1,) the cap's whole turn since the reset in degrees, counter-clockwise seen from above, read from the
        unwrapped joint."""
        return torch.rad2deg(self.bottle.get_qpos()[:, 0])

    def cap_turn_deg(self) -> torch.Tensor:
        """(1,) the turn that counts (theta): the cap's turn since the executor's motion stage started (since
        the reset when no stage started)."""
        return self.cap_angle_deg() - self._motion_start_deg

    def on_stage_start(self, stage: str) -> None:
        """Keep the cap's angle when the motion starts: the turn counts from there."""
        if stage == "motion":
            self._motion_start_deg = float(self.cap_angle_deg()[0])

    def watch_state(self) -> dict[str, float]:
        """The cap's angle (deg) when the motion started (0 before)."""
        return {"motion_start_deg": self._motion_start_deg}

    def set_watch_state(self, values: dict[str, float]) -> None:
        unknown = set(values) - {"motion_start_deg"}
        if unknown:
            raise ValueError(f"unknown unscrew watch state {sorted(unknown)}")
        self._motion_start_deg = float(values.get("motion_start_deg", self._motion_start_deg))

    def failure_decided(self, stage: str, reach: HandReach) -> str:
        """Decided once the cap and the bottle are asleep out of the hand's remaining reach
        (``at_rest_out_of_reach``): a success needs at least ``GRIP_LINKS`` hand links pressing on the cap's side
        at the end, and from here on the hand touches the cap no more."""
        frozen = self.at_rest_out_of_reach(reach)
        return f"{frozen}; the cap cannot be gripped at the end" if frozen else ""

    def tool_is_broken(self) -> torch.Tensor:
        """(1,) bool: the cap's simulated pose is NaN/inf (it cannot fall: it is jointed to the holder)."""
        return ~torch.isfinite(self.cap.pose.raw_pose).all(dim=-1)

    def gripping_links(self) -> list[str]:
        """Names of the hand links other than the palm that press on the cap's knurled side now (simulated
        contacts with a non-zero impulse; the smooth top disc does not count)."""
        cap_body = self.cap._objs[0]
        return [name for name in self.hand_links_touching(cap_body, cap_body.collision_shapes[0]) if name != "palm"]

    def evaluate(self) -> dict[str, torch.Tensor]:
        turn = self.cap_turn_deg()
        broken = self.tool_is_broken() | ~torch.isfinite(turn)
        gripped = len(self.gripping_links()) >= GRIP_LINKS
        return {
            "success": (turn > SUCCESS_DEG) & ~broken & gripped,
            "fail": broken,
            "gripped": torch.tensor([gripped]),
            "cap_turn_deg": torch.nan_to_num(turn, nan=0.0),
            "grasp_turn_deg": torch.tensor([self._motion_start_deg]),
            "cap_angle_deg": torch.nan_to_num(self.cap_angle_deg(), nan=0.0),
        }

    def _get_obs_extra(self, info: dict) -> dict[str, Any]:
        return {"cap_pose": self.cap.pose.raw_pose, "cap_turn_deg": info["cap_turn_deg"]}

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Reward = the cap's turn in degrees (paper: R_unscrewing = theta)."""
        return info["cap_turn_deg"].clone()

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        return self.compute_dense_reward(obs, action, info) / 90.0
