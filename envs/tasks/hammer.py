"""PRL hammering task (paper Sec. V-A): pick up a hammer and drive a nail into a board."""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np
import sapien
import torch
from mani_skill.utils.registration import register_env
from mani_skill.utils.structs import Actor, Articulation, Link
from sapien import physx

from envs.reach import HandReach
from envs.tasks.base import PRLTaskEnv, pose_from_matrix, pose_to_numpy, yaw_matrix
from prl.shapes import (
    HANDLE_HALF_LENGTH,
    HANDLE_RADIUS,
    HEAD_HALF_LENGTH,
    HEAD_RADIUS,
    NAIL_HEAD_RADIUS,
    NAIL_HEAD_THICKNESS,
    NAIL_PROTRUSION,
    NAIL_SHANK_RADIUS,
    SIZE_SCALE_RANGE,
    hammer_object_mesh,
    hammer_tool_mesh,
)
from prl.stages import StageSpec

# --- nominal geometry (metres); the randomised ones are scaled per episode --------------------------
# handle, head and nail sizes: defined once in prl.shapes (which rebuilds the meshes for PointNet)
HAMMER_MASS_RANGE = (0.2, 0.45)
"""Total hammer mass, kg (Adroit: 0.253)."""
HEAD_MASS_FRACTION = 0.5
"""Share of the hammer's mass in the head (densities are chosen per shape to hit it)."""
HAMMER_FRICTION_RANGE = (0.8, 1.5)
"""Static = dynamic friction coefficient of the hammer."""

HANDLE_AXIS_HEIGHT = 0.09
"""Height of the handle axis above the table when the hammer rests on its rack (>= 7 cm under the handle)."""
HAMMER_REST_XY = (-0.05, -0.10)
"""Nominal world (x, y) of the handle centre at rest; the handle points along world +X towards the head."""
HAMMER_REST_XY_RANGE = 0.03
"""Rack + hammer placement noise, +- metres in x and y."""
HAMMER_REST_YAW_RANGE = np.deg2rad(10.0)
"""Rack + hammer yaw noise, +- radians about world Z."""
HAMMER_ON_RACK_SHIFT = 0.01
"""Shift of the hammer along its handle relative to the rack, +- metres."""

BOARD_HALF_SIZE = (0.08, 0.08, 0.01)
"""Board half extents (Adroit: 0.08 x 0.08 x 0.01); the board lies on the table."""
BOARD_XY = (0.10, 0.12)
"""Nominal world (x, y) of the board centre (the nail sits at the board centre)."""
BOARD_XY_RANGE = 0.03
"""Board placement noise, +- metres in x and y."""
BOARD_YAW_RANGE = np.deg2rad(10.0)
"""Board yaw noise, +- radians (rotates the object frame's X/Y)."""
NAIL_MAX_DESCENT = NAIL_PROTRUSION - NAIL_HEAD_THICKNESS - 0.002
"""Upper limit of the nail joint (m): the head stops 2 mm above the board."""
NAIL_MASS = 0.02
"""Mass (kg) of the moving nail link (head + shank of a large nail)."""
NAIL_HOLD_FORCE_RANGE = (12.0, 18.0)
"""Nail friction: the force (N) the nail resists before sliding (Adroit: 'absorbs up to 15 N').
Always well above the heaviest hammer's weight (0.45 kg * 9.81 = 4.4 N) plus a light ~5 N touch."""
NAIL_FRICTION_DAMPING = 1e6
"""N s/m of the nail joint's velocity drive; with the force limit it acts as Coulomb friction
(force = min(damping * speed, hold force)): under a steady 10 N load the nail creeps 1e-5 m/s."""

SUCCESS_EPS_CM = 0.05
"""Descent (cm) above which the nail counts as driven (d > 0 cm in the paper); filters solver jitter."""
NAIL_MOVING_M = 1e-6
"""Nail motion (m) within one physics frame above which the frame's contacts on the nail head are read."""
FALL_HEIGHT = -0.05
"""A hammer whose origin is lower than this (m) has fallen off the table."""

NAIL_JOINT_Q = [0.7071068, 0.0, 0.7071068, 0.0]
"""Rotation about Y by +90 deg: maps the prismatic joint's X axis onto world -Z (qpos > 0 = descent)."""
X_TO_Z_Q = [0.7071068, 0.0, -0.7071068, 0.0]
"""Rotation about Y by -90 deg: a SAPIEN cylinder (axis X) becomes vertical (axis Z)."""
X_TO_Y_Q = [0.7071068, 0.0, 0.0, 0.7071068]
"""Rotation about Z by +90 deg: a SAPIEN cylinder (axis X) lies along Y."""

NAIL_DRIVERS: tuple[str, ...] = ("", "hand", "hammer", "loose_hammer")
"""What the nail watch says pressed on the nail head last (as saved in the state: its index): a hand link, the
hammer held by the hand (a hand link pressing on it in that frame), or the hammer with no hand on it."""

@register_env("PRL-Hammer-v1", max_episode_steps=150)
class PRLHammerEnv(PRLTaskEnv):
    """**Task Description:**
    The 30-DoF hand picks up a hammer resting on a rack and strikes a nail that sticks out of a board.
    The hammer is ONE dynamic rigid actor (held by contact and friction only): a capsule handle along
    its local X (= T_gv) and a cylindrical head at the +X end whose axis is the local Y (= T_fv). At
    rest the handle is horizontal along world +X (rotated by the rack's yaw) and the head's axis is
    vertical (local Y = world Z), so the head's -Y end face is the striking face. The handle's cylinder
    is supported at its butt end by a static block, the head by a second block under its bottom face,
    leaving the middle of the handle free with >= 7 cm below it for the fingers. The nail is a
    fixed-base articulation: a head disc on a prismatic joint along world -Z whose velocity drive with
    a force limit acts as Coulomb friction, so the hammer's weight or a light touch does not move it
    but a strike drives it in.

    **Randomizations:**
    - handle radius and half-length scaled together by a factor in [0.85, 1.15]; head radius and
      half-length by an independent factor in [0.85, 1.15]
    - hammer mass in [0.2, 0.45] kg (half of it in the head), hammer friction in [0.8, 1.5]
    - rack + hammer position +-3 cm in x, y and yaw +-10 deg; hammer shift along its handle on the
      rack +-1 cm
    - board (and nail) position +-3 cm in x, y and yaw +-10 deg
    - nail holding force (friction) in [12, 18] N

    **Success Conditions:**
    - d, the nail descent the hammer made, exceeds 0.05 cm (the paper's d > 0 cm, with an epsilon
      against solver jitter); ``success_1cm``: d > 1 cm. Each physics frame in which the nail moves
      is credited to what presses on its head then: the hand if any hand link does, else the hammer
      if it does **and a hand link presses on the hammer in that frame** (held), else the loose
      hammer, else whatever pressed last (the nail coasting). d is the held hammer's credit; a hand
      slammed onto the nail (the joint-control baseline's thumb, an impulse of ~10 N s in one frame)
      is not hammering, nor is a hammer that slipped out of the hand and fell on the nail, or one
      thrown at it (since 2026-12-02). ``nail_depth_cm`` is the joint's whole descent,
      ``hand_drive_cm`` the hand's part, ``loose_drive_cm`` the loose hammer's.
    - fail: the hammer fell off the table (origin below z = -5 cm) or the simulation produced NaN
    - reward (dense) = d in centimetres
    """

    task_name = "hammer"
    measure_key = "nail_descent_cm"
    measure_unit = "cm"
    tool_mesh = staticmethod(hammer_tool_mesh)
    object_mesh = staticmethod(hammer_object_mesh)
    evidence = ("nail_descent_cm", "nail_depth_cm", "hand_drive_cm", "loose_drive_cm")
    expert_plan = (0, 3, 2, 0, 0, 1)
    """No tilt, no twist, anchor 2, medium wrap, wrist swing, nail Z || head Y (the paper's Fig 2 / 7 choices)."""
    stages = StageSpec(
        shares=(("pregrasp", 0.17), ("approach", 0.07), ("grasp", 0.10), ("lift", 0.10), ("transport", 0.18),
                ("place", 0.08), ("motion", 0.30)),
        fv_approach=(0.0, 0.0, 1.0),
    )
    """Pick up -> carry -> strike: the head comes down onto the nail from above."""
    nail: Articulation
    """Fixed-base nail articulation: link ``nail_base`` (on the board) -> prismatic ``nail_joint`` -> ``nail_head``."""
    nail_head: Link
    """The moving nail link; its frame origin is on the board top at the nail axis (moves down with the nail)."""
    board: Actor

    # ------------------------------------------------------------------ scene
    def _load_scene(self, options: dict) -> None:
        rng = self._scene_rng()
        params = self._sample_params(rng)
        self.scene_params = params
        self._build_table()
        self._build_hammer(params)
        self._build_rack(params)
        self._build_board_and_nail(params)

    def _sample_params(self, rng: np.random.RandomState) -> dict[str, float]:
        """Draw one episode's randomised values (all SI units, plain floats; ranges scaled by ``randomization``)."""
        u = partial(self._uniform, rng)
        handle_scale = u(*SIZE_SCALE_RANGE)
        head_scale = u(*SIZE_SCALE_RANGE)
        values = {
            "handle_radius": HANDLE_RADIUS * handle_scale,
            "handle_half_length": HANDLE_HALF_LENGTH * handle_scale,
            "head_radius": HEAD_RADIUS * head_scale,
            "head_half_length": HEAD_HALF_LENGTH * head_scale,
            "hammer_mass": u(*HAMMER_MASS_RANGE),
            "hammer_friction": u(*HAMMER_FRICTION_RANGE),
            "rack_x": HAMMER_REST_XY[0] + u(-HAMMER_REST_XY_RANGE, HAMMER_REST_XY_RANGE),
            "rack_y": HAMMER_REST_XY[1] + u(-HAMMER_REST_XY_RANGE, HAMMER_REST_XY_RANGE),
            "rack_yaw": u(-HAMMER_REST_YAW_RANGE, HAMMER_REST_YAW_RANGE),
            "hammer_shift": u(-HAMMER_ON_RACK_SHIFT, HAMMER_ON_RACK_SHIFT),
            "board_x": BOARD_XY[0] + u(-BOARD_XY_RANGE, BOARD_XY_RANGE),
            "board_y": BOARD_XY[1] + u(-BOARD_XY_RANGE, BOARD_XY_RANGE),
            "board_yaw": u(-BOARD_YAW_RANGE, BOARD_YAW_RANGE),
            "nail_hold_force": u(*NAIL_HOLD_FORCE_RANGE),
        }
        return {key: float(value) for key, value in values.items()}

    def _head_center_x(self) -> float:
        """x of the head's centre in the hammer frame (the head touches the end of the handle's cylinder)."""
        return self.scene_params["handle_half_length"] + self.scene_params["head_radius"]

    def _build_hammer(self, params: dict[str, float]) -> None:
        r, hl = params["handle_radius"], params["handle_half_length"]
        hr, hhl = params["head_radius"], params["head_half_length"]
        mass_head = params["hammer_mass"] * HEAD_MASS_FRACTION
        mass_handle = params["hammer_mass"] - mass_head
        handle_volume = np.pi * r**2 * 2 * hl + 4.0 / 3.0 * np.pi * r**3
        head_volume = np.pi * hr**2 * 2 * hhl
        material = physx.PhysxMaterial(params["hammer_friction"], params["hammer_friction"], 0.0)
        head_x = self._head_center_x()

        builder = self.scene.create_actor_builder()
        builder.add_capsule_collision(
            radius=r, half_length=hl, material=material, density=mass_handle / handle_volume
        )
        builder.add_capsule_visual(
            radius=r, half_length=hl, material=sapien.render.RenderMaterial(base_color=[0.55, 0.35, 0.2, 1])
        )
        head_pose = sapien.Pose(p=[head_x, 0.0, 0.0], q=X_TO_Y_Q)
        builder.add_cylinder_collision(
            head_pose, radius=hr, half_length=hhl, material=material, density=mass_head / head_volume
        )
        builder.add_cylinder_visual(
            head_pose,
            radius=hr,
            half_length=hhl,
            material=sapien.render.RenderMaterial(base_color=[0.5, 0.5, 0.55, 1]),
        )
        builder.initial_pose = self._hammer_rest_pose()
        self.tool = builder.build_dynamic(name="hammer")
        params["hammer_mass"] = float(self.tool.mass[0])  # PhysX's mass of the built shapes (~0.3 % off)
        self.tool_gv_local = (np.zeros(3), np.array([hl, r, r]))
        self.tool_fv_local = (np.array([head_x, 0.0, 0.0]), np.array([hr, hhl, hr]))

    def _rack_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(origin on the table under the handle centre's nominal spot, R = yaw) of the rack."""
        p = self.scene_params
        return np.array([p["rack_x"], p["rack_y"], 0.0]), yaw_matrix(p["rack_yaw"])

    def _hammer_rest_pose(self) -> sapien.Pose:
        """Resting pose of the hammer frame: local X = rack's x axis, local Y = world Z (head vertical)."""
        origin, yaw = self._rack_frame()
        axes = np.column_stack([yaw[:, 0], [0.0, 0.0, 1.0], -yaw[:, 1]])  # X, Y=up, Z = X x Y
        position = origin + yaw @ np.array([self.scene_params["hammer_shift"], 0.0, HANDLE_AXIS_HEIGHT])
        return pose_from_matrix(position, axes)

    def _build_rack(self, params: dict[str, float]) -> None:
        """Two static blocks: one under the handle's butt end, one under the head's bottom face."""
        origin, yaw = self._rack_frame()
        angle = params["rack_yaw"]
        r, hl = params["handle_radius"], params["handle_half_length"]
        butt_top = HANDLE_AXIS_HEIGHT - r
        butt_half = np.array([0.015, 0.03, butt_top / 2])
        butt_center = origin + yaw @ np.array([-hl + 0.015, 0.0, 0.0]) + np.array([0, 0, butt_top / 2])
        self.rack_butt = self._build_static_box(
            "rack_butt", butt_center, butt_half, angle, (0.3, 0.3, 0.35, 1)
        )
        head_top = HANDLE_AXIS_HEIGHT - params["head_half_length"]
        head_half = np.array([params["head_radius"] + 0.02, params["head_radius"] + 0.02, head_top / 2])
        head_center = (
            origin + yaw @ np.array([self._head_center_x(), 0.0, 0.0]) + np.array([0, 0, head_top / 2])
        )
        self.rack_head = self._build_static_box(
            "rack_head", head_center, head_half, angle, (0.3, 0.3, 0.35, 1)
        )

    def _board_top_center(self) -> np.ndarray:
        p = self.scene_params
        return np.array([p["board_x"], p["board_y"], 2 * BOARD_HALF_SIZE[2]])

    def _build_board_and_nail(self, params: dict[str, float]) -> None:
        top = self._board_top_center()
        self.board = self._build_static_box(
            "board",
            top - np.array([0, 0, BOARD_HALF_SIZE[2]]),
            np.array(BOARD_HALF_SIZE),
            params["board_yaw"],
            (0.7, 0.55, 0.35, 1),
        )
        builder = self.scene.create_articulation_builder()
        base = builder.create_link_builder()
        base.set_name("nail_base")
        head = builder.create_link_builder(base)
        head.set_name("nail_head")
        nail_volume = np.pi * NAIL_HEAD_RADIUS**2 * NAIL_HEAD_THICKNESS
        head_center_z = NAIL_PROTRUSION - NAIL_HEAD_THICKNESS / 2
        head_pose = sapien.Pose(p=[0, 0, head_center_z], q=X_TO_Z_Q)
        head.add_cylinder_collision(
            head_pose,
            radius=NAIL_HEAD_RADIUS,
            half_length=NAIL_HEAD_THICKNESS / 2,
            density=NAIL_MASS / nail_volume,
        )
        grey = sapien.render.RenderMaterial(base_color=[0.75, 0.75, 0.8, 1])
        head.add_cylinder_visual(
            head_pose, radius=NAIL_HEAD_RADIUS, half_length=NAIL_HEAD_THICKNESS / 2, material=grey
        )
        shank_half = NAIL_PROTRUSION / 2 + 0.01
        head.add_cylinder_visual(
            sapien.Pose(p=[0, 0, NAIL_PROTRUSION / 2 - 0.01], q=X_TO_Z_Q),
            radius=NAIL_SHANK_RADIUS,
            half_length=shank_half,
            material=grey,
        )
        joint_frame = sapien.Pose(q=NAIL_JOINT_Q)
        head.set_joint_properties(
            "prismatic",
            limits=[[0.0, NAIL_MAX_DESCENT]],
            pose_in_parent=joint_frame,
            pose_in_child=joint_frame,
        )
        head.set_joint_name("nail_joint")
        builder.initial_pose = pose_from_matrix(top, yaw_matrix(params["board_yaw"]))
        self.nail = builder.build(name="nail", fix_root_link=True)
        self.nail_head = self.nail.links_map["nail_head"]
        self.nail_joint = self.nail.active_joints[0]
        self.nail_joint.set_drive_properties(0.0, NAIL_FRICTION_DAMPING, params["nail_hold_force"])
        self._nail_px, self._nail_head_px = self.nail._objs[0], self.nail_head._objs[0]  # PhysX objects, per frame
        self._reset_nail_watch()
        self.nail_joint.set_drive_velocity_target(torch.zeros(1))

    # ------------------------------------------------------------------ episode
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        """Place hammer and nail from this episode's ``scene_params`` (no new random draws)."""
        self.tool.set_pose(self._hammer_rest_pose())
        self.tool.set_linear_velocity(torch.zeros((1, 3)))
        self.tool.set_angular_velocity(torch.zeros((1, 3)))
        self.nail.set_qpos(torch.zeros((1, 1)))
        self.nail.set_qvel(torch.zeros((1, 1)))
        self._reset_nail_watch()
        self._reset_hand()

    def _reset_nail_watch(self) -> None:
        self._nail_q = 0.0  # the nail joint's qpos after the last watched frame (m)
        self._hammer_drive = 0.0  # nail motion (m) credited to the hammer held by the hand
        self._loose_drive = 0.0  # nail motion (m) by the hammer with no hand on it
        self._nail_driver = ""  # what pressed on the nail head in the last frame it moved: one of NAIL_DRIVERS

    def watch_state(self) -> dict[str, float]:
        """The nail watch's state: the nail's qpos at the last watched frame, the descent credited to the held and
        to the loose hammer, and what pressed on the head last (its index in ``NAIL_DRIVERS``)."""
        return {"nail_q": self._nail_q, "hammer_drive": self._hammer_drive, "loose_drive": self._loose_drive,
                "nail_driver": float(NAIL_DRIVERS.index(self._nail_driver))}

    def set_watch_state(self, values: dict[str, float]) -> None:
        unknown = set(values) - {"nail_q", "hammer_drive", "loose_drive", "nail_driver"}
        if unknown:
            raise ValueError(f"unknown hammer watch state {sorted(unknown)}")
        self._nail_q = float(values.get("nail_q", self._nail_q))
        self._hammer_drive = float(values.get("hammer_drive", self._hammer_drive))
        self._loose_drive = float(values.get("loose_drive", self._loose_drive))
        self._nail_driver = NAIL_DRIVERS[int(values.get("nail_driver", NAIL_DRIVERS.index(self._nail_driver)))]

    def _after_simulation_step(self) -> None:
        """Per physics frame: credit the nail's motion in this frame to what presses on its head (the class
        docstring). Contacts are read only in frames where the nail moves."""
        q = float(self._nail_px.get_qpos()[0])
        if abs(q - self._nail_q) > NAIL_MOVING_M:
            pressing = self.bodies_pressing(self._nail_head_px)  # one pass over the frame's contacts
            hammer = self.tool._bodies[0]
            if self.hand_links_among(pressing):
                self._nail_driver = "hand"
            elif any(b is hammer for b in pressing):  # held if a hand link presses on it now (a second pass)
                self._nail_driver = "hammer" if self.hand_links_touching(hammer) else "loose_hammer"
            if self._nail_driver == "hammer":
                self._hammer_drive += q - self._nail_q
            elif self._nail_driver == "loose_hammer":
                self._loose_drive += q - self._nail_q
        self._nail_q = q

    def failure_decided(self, stage: str, reach: HandReach) -> str:
        """Decided once the hammer, the nail and every other movable body are asleep out of the hand's remaining
        reach (``at_rest_out_of_reach``) while the held hammer's descent d is still at most ``SUCCESS_EPS_CM``.

        d grows only in a frame where the nail moves while the hammer presses on its head **and a hand link presses
        on the hammer**. From here on the hand touches neither the hammer nor the nail and neither moves (the nail
        is held by its friction drive), so d keeps its value: the episode ends a failure whatever the hand does.
        A hammer that keeps a hand link on it never qualifies (the hand's path starts where the hand is now)."""
        if self._hammer_drive * 100.0 > SUCCESS_EPS_CM:
            return ""
        frozen = self.at_rest_out_of_reach(reach)
        return f"{frozen}; the held hammer's descent stays {self._hammer_drive * 100.0:.3f} cm" if frozen else ""

    # ------------------------------------------------------------------ executor API
    def object_frame_world(self) -> tuple[np.ndarray, np.ndarray]:
        """Nail frame: origin at the centre of the nail head's top face (follows the simulated nail), Z up,
        X/Y along the board's edges."""
        position, rotation = pose_to_numpy(self.nail_head.pose.raw_pose)
        return position + rotation @ np.array([0.0, 0.0, NAIL_PROTRUSION]), rotation

    def nail_descent_cm(self) -> torch.Tensor:
        """(1,) the nail's whole descent in cm, read from the nail joint's simulated qpos (the hand's part included)."""
        return self.nail.get_qpos()[:, 0] * 100.0

    def evaluate(self) -> dict[str, torch.Tensor]:
        depth = self.nail_descent_cm()
        descent = torch.full_like(depth, self._hammer_drive * 100.0)  # what the hammer drove
        broken = self.tool_is_broken() | ~torch.isfinite(depth)
        return {
            "success": (descent > SUCCESS_EPS_CM) & ~broken,
            "success_1cm": (descent > 1.0) & ~broken,
            "fail": broken,
            "nail_descent_cm": torch.nan_to_num(descent, nan=0.0),
            "nail_depth_cm": torch.nan_to_num(depth, nan=0.0),
            "hand_drive_cm": torch.nan_to_num(depth - descent - self._loose_drive * 100.0, nan=0.0),
            "loose_drive_cm": torch.tensor([self._loose_drive * 100.0]),
        }

    def _get_obs_extra(self, info: dict) -> dict[str, torch.Tensor]:
        return {
            "hammer_pose": self.tool.pose.raw_pose,
            "nail_head_pose": self.nail_head.pose.raw_pose,
            "nail_descent_cm": info["nail_descent_cm"],
        }

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Reward = nail descent in cm (paper: R_hammering = d)."""
        return info["nail_descent_cm"].clone()

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        return self.compute_dense_reward(obs, action, info) / (NAIL_MAX_DESCENT * 100.0)
