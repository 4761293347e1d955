"""PRL sweeping task (paper Sec. V-A): pick up a broom, put it head-down and sweep debris cubes into a zone."""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np
import sapien
import torch
from mani_skill.utils.registration import register_env
from mani_skill.utils.structs import Actor
from sapien import physx

from envs.reach import HandReach
from envs.tasks.base import PRLTaskEnv, pose_from_matrix, pose_to_numpy, presses, yaw_matrix
from prl.geometry import rot_z
from prl.shapes import (
    BROOM_HANDLE_HALF_LENGTH,
    BROOM_HANDLE_RADIUS,
    BROOM_HEAD_HALF,
    DEBRIS_CUBE_SIZE_RANGE,
    SWEEP_CLEARANCE,
    sweep_object_mesh,
    sweep_tool_mesh,
)
from prl.stages import StageSpec

# --- nominal geometry (metres): broom and cube sizes are defined once in prl.shapes; scaled per episode -
SIZE_SCALE_RANGE = (0.9, 1.1)
"""Handle and head sizes are scaled each by an independent factor from this range."""
BROOM_MASS_RANGE = (0.15, 0.30)
"""Broom mass (kg); 40 % of it in the head."""
HEAD_MASS_FRACTION = 0.4
BROOM_FRICTION_RANGE = (0.8, 1.4)
"""Static = dynamic friction of the broom."""
REST_TILT = np.deg2rad(12.0)
"""The broom rests leaning on its rack: the handle rises by this angle from the head to the butt end."""
HANDLE_MID_HEIGHT = 0.09
"""Height of the handle axis's middle above the table at rest (>= 7 cm of room under it for the fingers)."""
BROOM_REST_XY = (-0.05, -0.10)
"""Nominal world (x, y) of the handle's middle at rest."""
BROOM_REST_XY_RANGE = 0.02
BROOM_REST_YAW_RANGE = np.deg2rad(8.0)

CUBE_MASS_RANGE = (0.005, 0.02)
CUBE_FRICTION_RANGE = (0.3, 0.7)
CUBE_COUNT_RANGE = (6, 8)
"""Debris cubes per scene, inclusive (the count is drawn, not scaled by ``randomization``)."""
SLOT_ROWS_X = (-0.04, -0.07)
"""x of the two rows of cube slots relative to the sweep line (the head's planned contact, the patch's front)."""
SLOT_COLS_Y = (-0.045, -0.015, 0.015, 0.045)
"""y of the four columns of cube slots relative to the patch centre."""
SLOT_JITTER = 0.002
"""Each cube sits within +-2 mm (x, y) of its slot centre and is turned by up to +-15 deg."""
CUBE_YAW_RANGE = np.deg2rad(15.0)
SWEEP_LINE_XY = (0.0, 0.12)
"""Nominal world (x, y) of the sweep line's centre: the object frame's origin, where the head's front face
crosses into the zone side; the sweep goes along world +X."""
SWEEP_LINE_XY_RANGE = 0.02
ZONE_OFFSET_RANGE = (0.0, 0.01)
"""Distance (m) from the sweep line to the zone's near edge along +X."""
ZONE_DEPTH = 0.16
"""Zone extent along +X (m)."""
ZONE_HALF_WIDTH = 0.09
"""Zone half extent along Y (m)."""
SUCCESS_COUNT = 3
"""Success: more than this many cubes end inside the zone (paper: N > 3)."""
CUBE_MOVING_MPS = 1e-3
"""A cube faster than this (m/s, any axis) is moving: the cube watch reads that frame's contacts."""
FALL_HEIGHT = -0.05


@register_env("PRL-Sweep-v1", max_episode_steps=150)
class PRLSweepEnv(PRLTaskEnv):
    """**Task Description:**
    The 30-DoF hand picks up a broom leaning on a rack, stands it head-down on the table and sweeps
    debris cubes along +X into a zone marked on the table. The broom is ONE dynamic rigid actor (held by
    contact and friction only): a capsule handle along its local X (= T_gv) and a head block at the -X end
    (= T_fv) whose +-Y faces push and whose -X face is the bottom when the broom stands. At rest the
    handle rises 12 deg from the head to the butt end, local Y points up (tilted by the same angle) and
    the head lies on a block tilted with it; a second block holds the butt end, leaving the middle of the
    handle free with >= 7 cm under it. The debris are 6-8 small dynamic cubes in a patch of 2 x 4 slots
    just behind the sweep line; the zone is a visual-only rectangle (no collision) beyond it.

    **Randomizations:**
    - handle radius and half-length scaled by a factor in [0.9, 1.1]; head by an independent factor
    - broom mass in [0.15, 0.30] kg (40 % in the head), friction in [0.8, 1.4]
    - rack position +-2 cm in x, y, yaw +-8 deg
    - cube count in {6, 7, 8} (which slots are used), each cube's edge in [1.5, 2] cm, mass in
      [5, 20] g, friction in [0.3, 0.7], +-2 mm and +-15 deg about its slot
    - sweep line (patch and zone) position +-2 cm in x, y; zone's near edge 0-1 cm past the sweep line

    **Success Conditions:**
    - more than 3 cube centres inside the zone at the end (paper: N > 3); every cube starts outside it. A cube
      counts only if the broom swept it: not one a hand link pressed on in any frame, nor one the broom pushed
      while no hand link held the broom (since 2026-12-02; a per-frame watch reads the contacts in frames where
      a cube moves). ``zone_cubes_hand_touched`` and ``zone_cubes_loose_pushed`` report the others in the zone
    - fail: the broom fell off the table or the simulation produced NaN
    - reward (dense) = N, the number of cubes in the zone; ``mean_displacement_cm`` reports how far the
      cubes moved
    """

    task_name = "sweep"
    measure_key = "cubes_in_zone"
    measure_unit = "cubes"
    tool_mesh = staticmethod(sweep_tool_mesh)
    object_mesh = staticmethod(sweep_object_mesh)
    evidence = ("cubes_in_zone", "zone_cubes_hand_touched", "zone_cubes_loose_pushed", "mean_displacement_cm")
    expert_plan = (0, 3, 2, 0, 2, 0)
    """No tilt, no twist, anchor 2, medium wrap on the handle, arm linear along X, the object's (table's)
    Z along T_fv's X: the broom stands head-down."""
    stages = StageSpec(
        shares=(("pregrasp", 0.15), ("approach", 0.07), ("grasp", 0.10), ("lift", 0.10), ("transport", 0.18),
                ("place", 0.10), ("motion", 0.30)),
        fv_approach=(0.0, 0.0, 1.0),
        motion_dir=(1.0, 0.0, 0.0),
        motion_scale=3.0,
        motion_s=0.6,
    )
    """Pick up -> stand the broom on its head behind the debris -> push along +X (10.5 cm and 60 % more, in 0.6 s)."""
    cubes: list[Actor]

    # ------------------------------------------------------------------ scene
    def _load_scene(self, options: dict) -> None:
        rng = self._scene_rng()
        params = self._sample_params(rng)
        self.scene_params = params
        self._build_table()
        self._build_broom(params)
        self._build_rack(params)
        self._build_debris(params)
        self._build_zone(params)

    def _sample_params(self, rng: np.random.RandomState) -> dict[str, float]:
        """Draw one episode's randomised values (plain floats, SI units; ranges scaled by ``randomization``)."""
        u = partial(self._uniform, rng)
        handle_scale, head_scale = u(*SIZE_SCALE_RANGE), u(*SIZE_SCALE_RANGE)
        values = {
            "handle_radius": BROOM_HANDLE_RADIUS * handle_scale,
            "handle_half_length": BROOM_HANDLE_HALF_LENGTH * handle_scale,
            "head_half_x": BROOM_HEAD_HALF[0] * head_scale,
            "head_half_y": BROOM_HEAD_HALF[1] * head_scale,
            "head_half_z": BROOM_HEAD_HALF[2] * head_scale,
            "broom_mass": u(*BROOM_MASS_RANGE),
            "broom_friction": u(*BROOM_FRICTION_RANGE),
            "rack_x": BROOM_REST_XY[0] + u(-BROOM_REST_XY_RANGE, BROOM_REST_XY_RANGE),
            "rack_y": BROOM_REST_XY[1] + u(-BROOM_REST_XY_RANGE, BROOM_REST_XY_RANGE),
            "rack_yaw": u(-BROOM_REST_YAW_RANGE, BROOM_REST_YAW_RANGE),
            "line_x": SWEEP_LINE_XY[0] + u(-SWEEP_LINE_XY_RANGE, SWEEP_LINE_XY_RANGE),
            "line_y": SWEEP_LINE_XY[1] + u(-SWEEP_LINE_XY_RANGE, SWEEP_LINE_XY_RANGE),
            "zone_offset": u(*ZONE_OFFSET_RANGE),
        }
        n_cubes = int(rng.randint(CUBE_COUNT_RANGE[0], CUBE_COUNT_RANGE[1] + 1))
        slots = rng.permutation(len(SLOT_ROWS_X) * len(SLOT_COLS_Y))[:n_cubes]
        values["n_cubes"] = n_cubes
        for i, slot in enumerate(sorted(int(s) for s in slots)):
            row, col = divmod(slot, len(SLOT_COLS_Y))
            values[f"cube{i}_x"] = values["line_x"] + SLOT_ROWS_X[row] + u(-SLOT_JITTER, SLOT_JITTER)
            values[f"cube{i}_y"] = values["line_y"] + SLOT_COLS_Y[col] + u(-SLOT_JITTER, SLOT_JITTER)
            values[f"cube{i}_yaw"] = u(-CUBE_YAW_RANGE, CUBE_YAW_RANGE)
            values[f"cube{i}_size"] = u(*DEBRIS_CUBE_SIZE_RANGE)
            values[f"cube{i}_mass"] = u(*CUBE_MASS_RANGE)
            values[f"cube{i}_friction"] = u(*CUBE_FRICTION_RANGE)
        return {key: float(value) for key, value in values.items()}

    def _broom_frame(self) -> np.ndarray:
        """Rotation of the broom at rest: X along the rising handle, Y up (tilted with it), Z = X x Y."""
        tilt = REST_TILT
        local = np.array([[np.cos(tilt), -np.sin(tilt), 0.0], [0.0, 0.0, -1.0], [np.sin(tilt), np.cos(tilt), 0.0]])
        return yaw_matrix(self.scene_params["rack_yaw"]) @ local

    def _broom_rest_pose(self) -> sapien.Pose:
        p = self.scene_params
        return pose_from_matrix(np.array([p["rack_x"], p["rack_y"], HANDLE_MID_HEIGHT]), self._broom_frame())

    def _head_center_x(self) -> float:
        """x of the head block's centre in the broom frame (the handle's -X cap ends in the head)."""
        return -(self.scene_params["handle_half_length"] + self.scene_params["head_half_x"])

    def _build_broom(self, params: dict[str, float]) -> None:
        r, hl = params["handle_radius"], params["handle_half_length"]
        head_half = np.array([params["head_half_x"], params["head_half_y"], params["head_half_z"]])
        mass_head = params["broom_mass"] * HEAD_MASS_FRACTION
        handle_volume = np.pi * r**2 * 2 * hl + 4.0 / 3.0 * np.pi * r**3
        material = physx.PhysxMaterial(params["broom_friction"], params["broom_friction"], 0.0)
        builder = self.scene.create_actor_builder()
        builder.add_capsule_collision(radius=r, half_length=hl, material=material,
                                      density=(params["broom_mass"] - mass_head) / handle_volume)
        builder.add_capsule_visual(radius=r, half_length=hl,
                                   material=sapien.render.RenderMaterial(base_color=[0.75, 0.6, 0.3, 1]))
        head_pose = sapien.Pose(p=[self._head_center_x(), 0.0, 0.0])
        builder.add_box_collision(head_pose, half_size=list(head_half), material=material,
                                  density=mass_head / float(np.prod(2 * head_half)))
        builder.add_box_visual(head_pose, half_size=list(head_half),
                               material=sapien.render.RenderMaterial(base_color=[0.2, 0.3, 0.6, 1]))
        builder.initial_pose = self._broom_rest_pose()
        self.tool = builder.build_dynamic(name="broom")
        params["broom_mass"] = float(self.tool.mass[0])
        self.tool_gv_local = (np.zeros(3), np.array([hl, r, r]))
        self.tool_fv_local = (np.array([self._head_center_x(), 0.0, 0.0]), head_half)

    def _build_rack(self, params: dict[str, float]) -> None:
        """A block under the head, tilted with it, and a block under the handle's butt end."""
        rest = self._broom_rest_pose().to_transformation_matrix()
        frame = self._broom_frame()
        head_half = np.array([params["head_half_x"], params["head_half_y"], params["head_half_z"]])
        # the head block: its top face is the head's -Y face; it reaches down into the table
        head_bottom = rest[:3, :3] @ np.array([self._head_center_x(), -head_half[1], 0.0]) + rest[:3, 3]
        depth = head_bottom[2] + 0.02
        block_half = np.array([head_half[0] + 0.01, depth / 2, head_half[2] + 0.01])
        center = head_bottom - frame[:, 1] * block_half[1]
        self.rack_head = self._build_static_box("rack_head", center, block_half, frame, (0.3, 0.3, 0.35, 1))
        # the butt block: flat top just under the handle's capsule at its +X end
        r, hl = params["handle_radius"], params["handle_half_length"]
        butt = rest[:3, :3] @ np.array([hl - 0.01, 0.0, 0.0]) + rest[:3, 3]
        top = butt[2] - r / np.cos(REST_TILT)
        butt_half = np.array([0.015, 0.03, top / 2])
        self.rack_butt = self._build_static_box("rack_butt", np.array([butt[0], butt[1], top / 2]), butt_half,
                                                params["rack_yaw"], (0.3, 0.3, 0.35, 1))

    def _cube_pose(self, i: int) -> sapien.Pose:
        p = self.scene_params
        return pose_from_matrix(np.array([p[f"cube{i}_x"], p[f"cube{i}_y"], p[f"cube{i}_size"] / 2]),
                                rot_z(p[f"cube{i}_yaw"]))

    def _build_debris(self, params: dict[str, float]) -> None:
        self.cubes = []
        self._reset_cube_watch(int(params["n_cubes"]))
        for i in range(int(params["n_cubes"])):
            size = params[f"cube{i}_size"]
            material = physx.PhysxMaterial(params[f"cube{i}_friction"], params[f"cube{i}_friction"], 0.0)
            builder = self.scene.create_actor_builder()
            builder.add_box_collision(half_size=[size / 2] * 3, material=material,
                                      density=params[f"cube{i}_mass"] / size**3)
            builder.add_box_visual(half_size=[size / 2] * 3,
                                   material=sapien.render.RenderMaterial(base_color=[0.85, 0.35, 0.2, 1]))
            builder.initial_pose = self._cube_pose(i)
            self.cubes.append(builder.build_dynamic(name=f"cube{i}"))
        self._cube_bodies = [cube._bodies[0] for cube in self.cubes]  # PhysX bodies, read every frame
        self._cube_index = {id(b): i for i, b in enumerate(self._cube_bodies)}  # PhysX body -> cube index

    def zone_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The zone as (min (2,), max (2,)) world (x, y) corners."""
        p = self.scene_params
        x0 = p["line_x"] + p["zone_offset"]
        return (np.array([x0, p["line_y"] - ZONE_HALF_WIDTH]), np.array([x0 + ZONE_DEPTH, p["line_y"] + ZONE_HALF_WIDTH]))

    def _build_zone(self, params: dict[str, float]) -> None:
        """A visual-only green rectangle 1 mm thick on the table (no collision: it pushes nothing)."""
        lo, hi = self.zone_box()
        builder = self.scene.create_actor_builder()
        builder.add_box_visual(half_size=[(hi[0] - lo[0]) / 2, (hi[1] - lo[1]) / 2, 0.0005],
                               material=sapien.render.RenderMaterial(base_color=[0.2, 0.7, 0.3, 1]))
        builder.initial_pose = sapien.Pose(p=[(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0005])
        self.zone = builder.build_static(name="zone")

    # ------------------------------------------------------------------ episode
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        """Place broom and cubes from this episode's ``scene_params`` (no new random draws)."""
        self.tool.set_pose(self._broom_rest_pose())
        for i, cube in enumerate(self.cubes):
            cube.set_pose(self._cube_pose(i))
        for body in [self.tool, *self.cubes]:
            body.set_linear_velocity(torch.zeros((1, 3)))
            body.set_angular_velocity(torch.zeros((1, 3)))
        self._reset_cube_watch(len(self.cubes))
        self._reset_hand()

    def _reset_cube_watch(self, n: int) -> None:
        self._hand_touched = np.zeros(n, bool)  # cubes a hand link pressed on in some frame
        self._loose_pushed = np.zeros(n, bool)  # cubes the broom pressed on while no hand link held it

    def _after_simulation_step(self) -> None:
        """Per physics frame in which a cube moves (faster than ``CUBE_MOVING_MPS``; sleeping cubes are skipped):
        mark the cubes a hand link presses on, and those the broom presses on while no hand link presses on the
        broom (a broom dropped or knocked onto the debris). One pass over the frame's contacts, only in such frames;
        a contact is asked whether it presses only if it joins a cube to the broom or the hand, and the grip's
        contacts only when the broom pushed a cube."""
        if not any(not b.is_sleeping and np.abs(b.get_linear_velocity()).max() > CUBE_MOVING_MPS
                   for b in self._cube_bodies):
            return
        broom = self.tool._bodies[0]
        hand = self._hand_link_names
        index = self._cube_index
        by_broom, grip = [], []
        for contact in self.scene.px.get_contacts():  # identity checks first: most contacts concern no cube
            a, b = contact.bodies
            for cube, other in ((a, b), (b, a)):
                i = index.get(id(cube))
                if i is not None and (other is broom or other.entity in hand) and presses(contact):
                    if other is broom:
                        by_broom.append(i)
                    else:
                        self._hand_touched[i] = True
            if (a is broom and b.entity in hand) or (b is broom and a.entity in hand):
                grip.append(contact)
        if by_broom and not any(presses(c) for c in grip):  # no hand link presses on the broom: it is loose
            self._loose_pushed[by_broom] = True

    def watch_state(self) -> dict[str, float]:
        """The cube watch's state: bit masks (bit i: cube i) of the cubes the hand touched and of those a loose
        broom pushed."""
        return {"hand_touched": float(sum(1 << i for i in np.flatnonzero(self._hand_touched))),
                "loose_pushed": float(sum(1 << i for i in np.flatnonzero(self._loose_pushed)))}

    def set_watch_state(self, values: dict[str, float]) -> None:
        unknown = set(values) - {"hand_touched", "loose_pushed"}
        if unknown:
            raise ValueError(f"unknown sweep watch state {sorted(unknown)}")
        n = len(self._hand_touched)
        for name, mask in (("hand_touched", self._hand_touched), ("loose_pushed", self._loose_pushed)):
            if name in values:
                bits = int(values[name])
                mask[:] = [(bits >> i) & 1 for i in range(n)]

    def failure_decided(self, stage: str, reach: HandReach) -> str:
        """Decided when at most ``SUCCESS_COUNT`` cubes can still count, or when nothing but the hand can move any
        more (``at_rest_out_of_reach``) and fewer than ``SUCCESS_COUNT`` + 1 cubes count now.

        A cube counts only if it ends in the zone, did not start there, and neither a hand link nor a loose broom
        ever pressed on it: the last two are marks the cube watch sets and never clears, so a cube marked (or one
        that started in the zone) never counts, and with at most 3 cubes left unmarked the count stays <= 3.
        Asleep and out of the hand's reach, the broom and every cube stay where they are and no mark changes (the
        watch marks only cubes that move), so the count and the broom's state at the end are those of now."""
        start = self.cube_start_positions()
        left = ~self._hand_touched & ~self._loose_pushed & ~self.cubes_in_zone(start)
        if int(left.sum()) <= SUCCESS_COUNT:
            return f"only {int(left.sum())} cubes can still count (the others were pressed by the hand or a loose broom)"
        frozen = self.at_rest_out_of_reach(reach)
        if not frozen:
            return ""
        now = self.evaluate()
        return "" if bool(now["success"][0]) else f"{frozen}; {int(now['cubes_in_zone'][0])} cubes count"

    # ------------------------------------------------------------------ executor API
    def object_frame_world(self) -> tuple[np.ndarray, np.ndarray]:
        """Sweep frame: origin on the sweep line's centre, ``SWEEP_CLEARANCE`` above the table; X = world +X
        (towards the zone), Z up. Fixed in the world (the table is the object the head comes onto)."""
        p = self.scene_params
        return np.array([p["line_x"], p["line_y"], SWEEP_CLEARANCE]), np.eye(3)

    def cube_positions(self) -> np.ndarray:
        """(n, 3) simulated cube centres."""
        return np.stack([pose_to_numpy(c.pose.raw_pose)[0] for c in self.cubes])

    def cube_start_positions(self) -> np.ndarray:
        """(n, 3) cube centres at the start of the episode (from ``scene_params``)."""
        p = self.scene_params
        return np.array([[p[f"cube{i}_x"], p[f"cube{i}_y"], p[f"cube{i}_size"] / 2] for i in range(len(self.cubes))])

    def cubes_in_zone(self, positions: np.ndarray) -> np.ndarray:
        """(n,) bool: which centres of ``positions`` (n, 3) lie inside the zone and on the table."""
        lo, hi = self.zone_box()
        xy = positions[:, :2]
        return np.all((xy >= lo) & (xy <= hi), axis=1) & (positions[:, 2] > -0.01)

    def evaluate(self) -> dict[str, torch.Tensor]:
        now = self.cube_positions()
        start = self.cube_start_positions()
        finite = bool(np.all(np.isfinite(now)))
        in_zone = self.cubes_in_zone(np.nan_to_num(now, nan=1e3)) & ~self.cubes_in_zone(start)
        counted = in_zone & ~self._hand_touched & ~self._loose_pushed
        n_in = int(counted.sum()) if finite else 0
        moved = float(np.mean(np.linalg.norm(now[:, :2] - start[:, :2], axis=1))) * 100.0 if finite else 0.0
        broken = self.tool_is_broken() | (not finite)
        as_tensor = partial(torch.tensor, device=self.device)
        return {
            "success": as_tensor([n_in > SUCCESS_COUNT]) & ~broken,
            "fail": broken,
            "cubes_in_zone": as_tensor([float(n_in)]),
            "mean_displacement_cm": as_tensor([moved]),
            "zone_cubes_hand_touched": as_tensor([float(np.sum(in_zone & self._hand_touched))]),
            "zone_cubes_loose_pushed": as_tensor([float(np.sum(in_zone & self._loose_pushed & ~self._hand_touched))]),
        }

    def _get_obs_extra(self, info: dict) -> dict[str, Any]:
        return {"broom_pose": self.tool.pose.raw_pose, "cubes_in_zone": info["cubes_in_zone"]}

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Reward = number of cubes in the zone (paper: R_sweeping = N)."""
        return info["cubes_in_zone"].clone()

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        return self.compute_dense_reward(obs, action, info) / max(1, len(self.cubes))
