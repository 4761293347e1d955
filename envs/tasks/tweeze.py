"""PRL tweezing task (paper Sec. V-A): squeeze a pair of tweezers on a small cube and lift it."""

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
from prl.geometry import rot_y, rot_z
from prl.shapes import (
    TWEEZERS_ARM_HEIGHT,
    TWEEZERS_ARM_THICKNESS,
    TWEEZERS_BUTT_LENGTH,
    TWEEZERS_LINK_IN_FRAME,
    tweeze_object_mesh,
    tweeze_tool_mesh,
    tweezers_arm_angle,
)
from prl.stages import StageSpec

# --- randomised geometry and physics (metres, kilograms, newtons) --------------------------------
ARM_LENGTH_RANGE = (0.15, 0.17)
"""Length of each arm from the hinge at the butt to its tip."""
TIP_GAP_RANGE = (0.040, 0.046)
"""Gap between the tips' inner faces when the spring holds the tweezers open."""
SPRING_STIFFNESS_RANGE = (1.0, 2.0)
"""Hinge spring, N m/rad: a drive with stiffness toward the open angle (docs/guide/design.md "Mechanisms as drives"); shut, the tips press
0.2-0.5 N m back against the fingers, which press with up to 1.5-2 N m per joint (``envs/agents/prl_hand.py``)."""
SPRING_DAMPING = 1.0
"""Hinge damping, N m s/rad. Undamped, a saturated pinch swung the 10 g arm shut at ~4 rad/s and the tip struck
the cube away; damped, the tips close at ~1 rad/s and the released spring reopens them in ~1 s."""
TWEEZERS_MASS = 0.02
TWEEZERS_FRICTION_RANGE = (0.8, 1.2)
CUBE_SIZE_RANGE = (0.020, 0.025)
"""Edge of the cube (paper: a small cube)."""
CUBE_MASS_RANGE = (0.004, 0.015)
CUBE_FRICTION_RANGE = (0.6, 1.0)
TWEEZERS_XY = (-0.10, -0.10)
"""Nominal world (x, y) of the hinge; the arms point along world -X (turned by the yaw)."""
TWEEZERS_XY_RANGE = 0.02
TWEEZERS_YAW_RANGE = np.deg2rad(10.0)
CUBE_OFFSET_RANGE = 0.003
"""The cube lies between the open tips, +- this far along and across the arms from the nominal spot."""
CUBE_INSIDE = 0.008
"""The cube's far face lies this far inside the tips (m)."""
CUBE_SIDE = -0.6
"""Where the cube lies across the gap between the arms: -1 against arm a, +1 against arm b. Arm a (with the
butt) stands in the cradle and does not move, so the pinch swings arm b onto the cube and pushes it the short
way left to arm a; near arm b, the longer push turned the cube and the converging tips squeezed it out past
their ends (expert 21/30 at +0.4, 29/30 at -0.6, scenes 0-29)."""
REST_HEIGHT = 0.09
"""Height (m) of the arms' centre line at rest: the tweezers lie on a rack, as the hammer does, with room under
their middle for the fingers (the palmar pinch takes a thin rod at this height, ``envs/tasks/grasp_probe.py``)."""
GV_AT = (0.4, 0.6)
"""T_gv: the arms between these fractions of their length from the hinge (the palm's anchor goes over its
centre)."""
SUPPORT_AT = (0.55, 0.65)
"""The rack's middle block carries the arms between these fractions of their length (clear of T_gv and T_fv)."""
CRADLE_REACH = 0.02
"""The cradle's side walls run from behind the butt to this far along the arms from the hinge (m)."""
CRADLE_CLEARANCE = 0.0005
"""Play (m) between the butt and the cradle's walls."""
CRADLE_WALL = 0.006
"""Thickness (m) of the cradle's walls."""
CRADLE_HEIGHT = 0.010
"""Height (m) of the cradle's walls above the rack (the arms are 1.2 cm tall: the fingers reach over them)."""
PLATFORM_FROM = 0.8
"""The tips' rest, a block as high as the rack that also carries the cube, starts this fraction of the arms'
length from the hinge and reaches 2 cm past the tips."""
SUCCESS_LIFT_CM = 10.0
"""Success: the cube's lowest point more than this far above where it rested (paper: l > 10 cm)."""
POST_LIFT = 0.15
"""How far the hand rises after the motion (``post_lift``), metres."""


def _in_link(center: np.ndarray, rotation: np.ndarray) -> sapien.Pose:
    """A pose given in the tweezers' frame (X towards the tips), expressed in their root link's frame."""
    return pose_from_matrix(TWEEZERS_LINK_IN_FRAME.T @ center, TWEEZERS_LINK_IN_FRAME.T @ rotation)


def _box_corners(center: np.ndarray, half: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(8, 3) world corners of an oriented box."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    return center + (signs * half) @ rotation.T


@register_env("PRL-Tweeze-v1", max_episode_steps=150)
class PRLTweezeEnv(PRLTaskEnv):
    """**Task Description:**
    The 30-DoF hand squeezes a pair of tweezers shut on a small cube and lifts it. The tweezers are a
    free-floating articulation (no fixed root): two thin arms (1.2 cm tall, 3 mm thick) joined at the butt by a
    revolute hinge about their height axis, whose damped drive, stiffness toward the open angle, is the spring
    that keeps them apart. They lie open on a rack: the butt stands in a
    cradle (a block with low walls behind and beside it, open on top), a block carries the arms past their
    middle, and a third carries the tips and the cube between them. Only the fingers' squeeze on the arms
    closes them, and only the tips' friction can then carry the cube. The fingers' drives press with up to
    1.5-2 N m per joint (``envs/agents/prl_hand.py``), far more than the spring, so a grasp that squeezes the
    arms shuts the tweezers during the grasp itself: the tips must already stand around the cube (a plan cannot
    carry open tweezers to it with this hand and executor). The cradle keeps a pinch from shoving or turning
    the free tweezers before both fingers hold them; the tweezers lift straight out of it.

    The RS reads here: the tool is the tweezers, whose frame (their root link's, ``TWEEZERS_LINK_IN_FRAME``)
    has X from the tips towards the butt, Y up (T_gv = the arms between 40% and 60% of their length, where the
    palm's anchor goes; T_fv = the last 2 cm of the arms, the tips); the object is the cube (frame: its bottom
    face's centre, Z up). There is no transport or place: the motion acts from the grasp (finger_squeeze
    presses harder), then the task lifts the hand by 15 cm (``post_lift``); a5 is not acted on.

    **Randomizations:**
    - arm length in [15, 17] cm, open tip gap in [4.0, 4.6] cm, spring stiffness in [1, 2] N m/rad,
      tweezers friction in [0.8, 1.2]
    - cube edge in [2.0, 2.5] cm, mass in [4, 15] g, friction in [0.6, 1.0], its spot between the tips +-3 mm
      (nearer arm a, ``CUBE_SIDE``)
    - tweezers (and cube) position +-2 cm in x, y and yaw +-10 deg

    **Success Conditions:**
    - the cube's lowest point more than 10 cm above the block it rested on at the end, and no hand link
      pressed on it in any physics frame of the episode (held by the tips only; a per-frame watch); reward =
      the lift l in cm; ``between_tips`` reports whether the cube's centre lies between the arms' last 3 cm
    - fail: the tweezers fell off the table or the simulation produced NaN
    """

    task_name = "tweeze"
    measure_key = "cube_lift_cm"
    measure_unit = "cm"
    tool_mesh = staticmethod(tweeze_tool_mesh)
    object_mesh = staticmethod(tweeze_object_mesh)
    evidence = ("cube_lift_cm", "hand_touches_cube", "between_tips")
    expert_plan = (2, 1, 4, 2, 6, 1)
    """Palm tilted by -10 deg and turned by -20 deg (its little-finger side away from the tips: untwisted, it
    brushed the cube on the way up), anchor 4, palmar pinch across the arms, finger squeeze, object Z || T_fv Y:
    a5 is not acted on (no place stage), so the expert commands what the recording reads (X until 2026-12-02,
    with the same physics: the executor reads a5 only to plan a place)."""
    unacted_dims = ("tool_object_rot",)
    stages = StageSpec(
        shares=(("pregrasp", 0.22), ("approach", 0.12), ("grasp", 0.22), ("motion", 0.16), ("post_lift", 0.28)),
        fv_approach=(0.0, 0.0, 1.0),
        post_lift_height=POST_LIFT,
        motion_s=0.3,
    )
    """Pinch the arms where they lie (the tips around the cube), squeeze, then lift."""
    tweezers: Articulation
    arm_b: Link
    cube: Actor

    # ------------------------------------------------------------------ scene
    def _load_scene(self, options: dict) -> None:
        self._hand_touched_cube: list[str] = []  # also before the first episode (the state is read at construction)
        rng = self._scene_rng()
        u = partial(self._uniform, rng)
        self.scene_params = params = {
            "arm_length": u(*ARM_LENGTH_RANGE),
            "tip_gap": u(*TIP_GAP_RANGE),
            "spring_stiffness": u(*SPRING_STIFFNESS_RANGE),
            "tweezers_friction": u(*TWEEZERS_FRICTION_RANGE),
            "cube_size": u(*CUBE_SIZE_RANGE),
            "cube_mass": u(*CUBE_MASS_RANGE),
            "cube_friction": u(*CUBE_FRICTION_RANGE),
            "tweezers_x": TWEEZERS_XY[0] + u(-TWEEZERS_XY_RANGE, TWEEZERS_XY_RANGE),
            "tweezers_y": TWEEZERS_XY[1] + u(-TWEEZERS_XY_RANGE, TWEEZERS_XY_RANGE),
            "tweezers_yaw": u(-TWEEZERS_YAW_RANGE, TWEEZERS_YAW_RANGE),
            "cube_along": u(-CUBE_OFFSET_RANGE, CUBE_OFFSET_RANGE),
            "cube_across": u(-CUBE_OFFSET_RANGE, CUBE_OFFSET_RANGE),
        }
        self._build_table()
        self._build_tweezers(params)
        self._build_rack(params)
        self._build_cube(params)

    def _rest_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """The tweezers' frame at rest, (origin, R): origin at the hinge, X along the arms towards the tips, Y up,
        Z across. The tips point at world -X (turned by the yaw): with no twist the executor's hand comes down
        with its fingers along world +X and pinches a few cm ahead of its palm anchor (the grasp probe's rod,
        ``envs/tasks/grasp_probe.py``), so the fingers curl onto the arms towards the butt, away from the cube."""
        p = self.scene_params
        yaw = yaw_matrix(p["tweezers_yaw"] + np.pi)
        axes = np.column_stack([yaw[:, 0], [0.0, 0.0, 1.0], -yaw[:, 1]])  # X along the arms, Y up, Z across
        return np.array([p["tweezers_x"], p["tweezers_y"], REST_HEIGHT]), axes

    def _rest_pose(self) -> sapien.Pose:
        """The root link's pose at rest: the tweezers' frame turned by ``TWEEZERS_LINK_IN_FRAME``."""
        origin, rotation = self._rest_frame()
        return pose_from_matrix(origin, rotation @ TWEEZERS_LINK_IN_FRAME)

    def _cube_rest(self) -> tuple[np.ndarray, np.ndarray]:
        """(centre, R) of the cube at rest: on the tips' block between the open tips, its far face ``CUBE_INSIDE``
        inside them."""
        p = self.scene_params
        origin, rotation = self._rest_frame()
        along = p["arm_length"] - CUBE_INSIDE - p["cube_size"] / 2 + p["cube_along"]
        gap = p["tip_gap"] * (along - p["cube_size"] / 2) / p["arm_length"]  # between the arms at the cube's near face
        across = CUBE_SIDE * (gap - p["cube_size"]) / 2 + p["cube_across"]  # +: towards arm b (+z)
        center = origin + rotation @ np.array([along, 0.0, across])
        center[2] = self.rest_surface() + p["cube_size"] / 2
        return center, yaw_matrix(p["tweezers_yaw"])

    @staticmethod
    def rest_surface() -> float:
        """Height (m) of the rack's tops: the arms' bottom edges and the cube's bottom face."""
        return REST_HEIGHT - TWEEZERS_ARM_HEIGHT / 2

    def _build_rack(self, params: dict[str, float]) -> None:
        """Static blocks: the butt's cradle, one under the arms past their middle, one under the tips and the cube."""
        origin, rotation = self._rest_frame()
        yaw, top = params["tweezers_yaw"], self.rest_surface()
        length, half_angle = params["arm_length"], tweezers_arm_angle(params["arm_length"], params["tip_gap"])
        grey = (0.3, 0.3, 0.35, 1)
        butt = origin + rotation @ np.array([-TWEEZERS_BUTT_LENGTH / 2, 0.0, 0.0])
        self.rack_butt = self._build_static_box("rack_butt", np.array([butt[0], butt[1], top / 2]),
                                                np.array([TWEEZERS_BUTT_LENGTH / 2 + 0.005, 0.015, top / 2]), yaw, grey)
        lo, hi = SUPPORT_AT
        mid = origin + rotation @ np.array([(lo + hi) / 2 * length, 0.0, 0.0])
        across = hi * length * np.sin(half_angle) + 2 * TWEEZERS_ARM_THICKNESS + 0.005
        self.rack_arms = self._build_static_box("rack_arms", np.array([mid[0], mid[1], top / 2]),
                                                np.array([(hi - lo) / 2 * length, across, top / 2]), yaw, grey)
        # the cradle: walls beside the butt and the arms' first 2 cm and one behind the butt, so a push across or
        # along the arms cannot shift or turn the tweezers; they lift straight out of it
        x0, x1 = -TWEEZERS_BUTT_LENGTH - CRADLE_CLEARANCE, CRADLE_REACH
        arm_outer = CRADLE_REACH * np.sin(half_angle) + TWEEZERS_ARM_THICKNESS * np.cos(half_angle)
        inner = max(2 * TWEEZERS_ARM_THICKNESS, arm_outer) + CRADLE_CLEARANCE  # clear of the butt and the open arms
        for side in (-1.0, 1.0):
            c = origin + rotation @ np.array([(x0 + x1) / 2, 0.0, side * (inner + CRADLE_WALL / 2)])
            self._build_static_box(f"cradle_{'ab'[side > 0]}", np.array([c[0], c[1], top + CRADLE_HEIGHT / 2]),
                                   np.array([(x1 - x0) / 2, CRADLE_WALL / 2, CRADLE_HEIGHT / 2]), yaw, grey)
        back = origin + rotation @ np.array([x0 - CRADLE_WALL / 2, 0.0, 0.0])
        self._build_static_box("cradle_back", np.array([back[0], back[1], top + CRADLE_HEIGHT / 2]),
                               np.array([CRADLE_WALL / 2, inner + CRADLE_WALL, CRADLE_HEIGHT / 2]), yaw, grey)
        # the tips' rest: a block under the arms' last cm and the cube, level with the other two (a wider rest
        # than a post: the cube pushed across by the closing tips stays on it)
        lo = PLATFORM_FROM * length
        hi = length * np.cos(half_angle) + 0.02
        mid = origin + rotation @ np.array([(lo + hi) / 2, 0.0, 0.0])
        across = length * np.sin(half_angle) + 2 * TWEEZERS_ARM_THICKNESS + 0.01
        self._build_static_box("platform", np.array([mid[0], mid[1], top / 2]),
                               np.array([(hi - lo) / 2, across, top / 2]), yaw, grey)

    def _build_tweezers(self, params: dict[str, float]) -> None:
        length, half_angle = params["arm_length"], tweezers_arm_angle(params["arm_length"], params["tip_gap"])
        material = physx.PhysxMaterial(params["tweezers_friction"], params["tweezers_friction"], 0.0)
        steel = sapien.render.RenderMaterial(base_color=[0.72, 0.74, 0.78, 1])
        arm_half = np.array([length / 2, TWEEZERS_ARM_HEIGHT / 2, TWEEZERS_ARM_THICKNESS / 2])
        arm_volume = float(np.prod(2 * arm_half))
        butt_half = np.array([TWEEZERS_BUTT_LENGTH / 2, TWEEZERS_ARM_HEIGHT / 2, 2 * TWEEZERS_ARM_THICKNESS])
        density = TWEEZERS_MASS / (2 * arm_volume + float(np.prod(2 * butt_half)))

        builder = self.scene.create_articulation_builder()
        root = builder.create_link_builder()
        root.set_name("arm_a")
        for pose, half in ((self._arm_pose(length, half_angle, -1.0), arm_half),
                           (_in_link(np.array([-TWEEZERS_BUTT_LENGTH / 2, 0.0, 0.0]), np.eye(3)), butt_half)):
            root.add_box_collision(pose, half_size=list(half), material=material, density=density)
            root.add_box_visual(pose, half_size=list(half), material=steel)
        arm = builder.create_link_builder(root)
        arm.set_name("arm_b")
        pose = self._arm_pose(length, half_angle, +1.0)
        arm.add_box_collision(pose, half_size=list(arm_half), material=material, density=density)
        arm.add_box_visual(pose, half_size=list(arm_half), material=steel)
        # the hinge about the tweezers' Y (up) at the butt; qpos > 0 swings arm b (+Z side) towards arm a (closing)
        hinge = _in_link(np.zeros(3), rot_z(np.pi / 2))  # the joint's X axis onto the tweezers' Y
        closed = 2 * half_angle - TWEEZERS_ARM_THICKNESS / length  # the tips' inner faces meet
        arm.set_joint_properties("revolute", limits=[[-0.02, closed]], pose_in_parent=hinge, pose_in_child=hinge)
        arm.set_joint_name("hinge")
        builder.initial_pose = self._rest_pose()
        self.tweezers = builder.build(name="tweezers", fix_root_link=False)
        self.arm_b = self.tweezers.links_map["arm_b"]
        self.hinge = self.tweezers.active_joints[0]
        self.hinge._objs[0].set_friction(0.0)
        # the damped spring reopens the arms slowly (0.05 rad/s near the end), below PhysX's default sleep
        # threshold, which froze them part-open; they never sleep instead
        self.tweezers._objs[0].set_sleep_threshold(0.0)
        self.hinge.set_drive_properties(params["spring_stiffness"], SPRING_DAMPING, 10.0)
        self.hinge.set_drive_target(torch.zeros(1))
        self.tool = self.tweezers.links_map["arm_a"]
        gap_gv = 2 * GV_AT[1] * length * np.sin(half_angle) + TWEEZERS_ARM_THICKNESS  # the arms' outer faces
        self.tool_gv_local = (TWEEZERS_LINK_IN_FRAME.T @ np.array([(GV_AT[0] + GV_AT[1]) * length / 2, 0.0, 0.0]),
                              np.array([(GV_AT[1] - GV_AT[0]) * length / 2, TWEEZERS_ARM_HEIGHT / 2,
                                        gap_gv / 2 + TWEEZERS_ARM_THICKNESS]))
        self.tool_fv_local = (TWEEZERS_LINK_IN_FRAME.T @ np.array([length - 0.01, 0.0, 0.0]),
                              np.array([0.01, TWEEZERS_ARM_HEIGHT / 2, params["tip_gap"] / 2 + TWEEZERS_ARM_THICKNESS]))

    @staticmethod
    def _arm_pose(length: float, half_angle: float, side: float) -> sapien.Pose:
        """An arm's box pose in the link frame: from the hinge towards the ``side`` (+1: +Z) by the half opening
        angle, turned about Y, its inner face on the line from the hinge (the arms meet there)."""
        rotation = rot_y(-side * half_angle)  # x onto (cos, 0, side * sin)
        center = rotation @ np.array([length / 2, 0.0, side * TWEEZERS_ARM_THICKNESS / 2])
        return _in_link(center, rotation)

    def _build_cube(self, params: dict[str, float]) -> None:
        half = params["cube_size"] / 2
        material = physx.PhysxMaterial(params["cube_friction"], params["cube_friction"], 0.0)
        builder = self.scene.create_actor_builder()
        builder.add_box_collision(half_size=[half] * 3, material=material,
                                  density=params["cube_mass"] / params["cube_size"] ** 3)
        builder.add_box_visual(half_size=[half] * 3, material=sapien.render.RenderMaterial(base_color=[0.2, 0.45, 0.8, 1]))
        center, rotation = self._cube_rest()
        builder.initial_pose = pose_from_matrix(center, rotation)
        self.cube = builder.build_dynamic(name="cube")

    # ------------------------------------------------------------------ episode
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        """Place tweezers (open) and cube from this episode's ``scene_params`` (no new random draws)."""
        self.tweezers.set_root_pose(self._rest_pose())
        self.tweezers.set_qpos(torch.zeros((1, 1)))
        self.tweezers.set_qvel(torch.zeros((1, 1)))
        self.tweezers.set_root_linear_velocity(torch.zeros((1, 3)))
        self.tweezers.set_root_angular_velocity(torch.zeros((1, 3)))
        center, rotation = self._cube_rest()
        self.cube.set_pose(pose_from_matrix(center, rotation))
        self.cube.set_linear_velocity(torch.zeros((1, 3)))
        self.cube.set_angular_velocity(torch.zeros((1, 3)))
        self._hand_touched_cube = []  # hand links that pressed on the cube in any frame so far
        self._reset_hand()

    def _after_simulation_step(self) -> None:
        """Per physics frame: remember any hand link that presses on the cube (a success needs a cube the hand
        never touched, not only one it lets go of by the end). It reads every frame's contacts until the first
        touch: an expert episode takes 1.12x as long as without the watch (16 scenes, run alternately)."""
        if not self._hand_touched_cube:
            self._hand_touched_cube = self.hand_touches_cube()

    def watch_state(self) -> dict[str, float]:
        """The cube watch's state: 1 + the index (in the sorted hand link names) of the first hand link that pressed
        on the cube in this episode, 0 if none did."""
        names = sorted(self._hand_link_names.values())
        return {"touched_link": float(names.index(self._hand_touched_cube[0]) + 1) if self._hand_touched_cube else 0.0}

    def set_watch_state(self, values: dict[str, float]) -> None:
        unknown = set(values) - {"touched_link"}
        if unknown:
            raise ValueError(f"unknown tweeze watch state {sorted(unknown)}")
        k = int(values.get("touched_link", 0))
        self._hand_touched_cube = [sorted(self._hand_link_names.values())[k - 1]] if k > 0 else []

    # ------------------------------------------------------------------ executor API
    def object_frame_world(self) -> tuple[np.ndarray, np.ndarray]:
        """The cube's frame: origin at its bottom face's centre (follows the simulated cube), Z up, X/Y along
        the tweezers' arms and across them at rest."""
        position, rotation = pose_to_numpy(self.cube.pose.raw_pose)
        return position - np.array([0.0, 0.0, self.scene_params["cube_size"] / 2]), rotation

    def tweezers_opening(self) -> float:
        """How far the hinge has closed from the spring's open angle, radians (0 = open)."""
        return float(self.tweezers.get_qpos()[0, 0])

    def cube_lift_cm(self) -> torch.Tensor:
        """(1,) lift of the cube in cm: how far its lowest corner is above the block it rested on."""
        position, rotation = pose_to_numpy(self.cube.pose.raw_pose)
        half = np.full(3, self.scene_params["cube_size"] / 2)
        return torch.tensor([(float(_box_corners(position, half, rotation)[:, 2].min()) - self.rest_surface()) * 100.0])

    def cube_between_tips(self) -> bool:
        """Whether the cube's centre lies between the arms' last 3 cm (in the tweezers' frame)."""
        tool_p, tool_r = pose_to_numpy(self.tool.pose.raw_pose)
        cube_p, _ = pose_to_numpy(self.cube.pose.raw_pose)
        local = TWEEZERS_LINK_IN_FRAME @ tool_r.T @ (cube_p - tool_p)
        length = self.scene_params["arm_length"]
        return bool(length - 0.03 <= local[0] <= length + 0.005 and abs(local[2]) <= self.scene_params["tip_gap"] / 2
                    and abs(local[1]) <= TWEEZERS_ARM_HEIGHT + self.scene_params["cube_size"])

    def hand_touches_cube(self) -> list[str]:
        """Names of the hand links in contact with the cube now (simulated contacts with a non-zero impulse)."""
        return self.hand_links_touching(self.cube._bodies[0])

    def hand_touched_cube(self) -> list[str]:
        """The hand links that pressed on the cube in a frame of this episode (the first frame with any), or that
        press on it now."""
        return self._hand_touched_cube or self.hand_touches_cube()

    def failure_decided(self, stage: str, reach: HandReach) -> str:
        """Decided as soon as a hand link has pressed on the cube: the cube watch keeps that first touch for the
        rest of the episode and ``evaluate()`` never counts a touched cube, whatever happens next.

        (``at_rest_out_of_reach`` never holds here: the tweezers never sleep, their sleep threshold is 0.)"""
        if self._hand_touched_cube:
            return f"hand link {self._hand_touched_cube[0]} pressed on the cube"
        frozen = self.at_rest_out_of_reach(reach)
        lift = float(self.cube_lift_cm()[0]) if frozen else 0.0
        return f"{frozen}; the cube's lift stays {lift:.1f} cm" if frozen and not lift > SUCCESS_LIFT_CM else ""

    def tool_is_broken(self) -> torch.Tensor:
        broken = super().tool_is_broken()
        arm = self.arm_b.pose.raw_pose
        return broken | ~torch.isfinite(arm).all(dim=-1) | ~torch.isfinite(self.cube.pose.raw_pose).all(dim=-1)

    def evaluate(self) -> dict[str, torch.Tensor]:
        lift = self.cube_lift_cm()
        broken = self.tool_is_broken() | ~torch.isfinite(lift)
        touched = bool(self.hand_touched_cube())
        return {
            "success": (lift > SUCCESS_LIFT_CM) & ~broken & torch.tensor([not touched]),
            "fail": broken,
            "hand_touches_cube": torch.tensor([touched]),
            "between_tips": torch.tensor([self.cube_between_tips()]),
            "cube_lift_cm": torch.nan_to_num(lift, nan=0.0),
        }

    def _get_obs_extra(self, info: dict) -> dict[str, Any]:
        return {"tweezers_pose": self.tool.pose.raw_pose, "cube_pose": self.cube.pose.raw_pose,
                "hinge_qpos": self.tweezers.get_qpos(), "cube_lift_cm": info["cube_lift_cm"]}

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Reward = the cube's lift in cm (paper: R_tweezing = l)."""
        return info["cube_lift_cm"].clone()

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        return self.compute_dense_reward(obs, action, info) / SUCCESS_LIFT_CM
