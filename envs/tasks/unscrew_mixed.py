"""PRL unscrewing task, mixed variant (issue #26): a small cap on an upright wide-shouldered flask, or a wide tight lid
on a bottle lying on its side in a cradle."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import ClassVar

import numpy as np
import trimesh
from mani_skill.utils.registration import register_env
from mani_skill.utils.structs import Pose

from envs.tasks.base import pose_from_matrix
from envs.tasks.mixed import MixedFamilies
from envs.tasks.unscrew import (
    BODY_HEIGHT_RANGE,
    BODY_RADIUS_RANGE,
    BOTTLE_XY,
    BOTTLE_XY_RANGE,
    CAP_FRICTION_RANGE,
    CAP_HALF_HEIGHT_RANGE,
    PRLUnscrewEnv,
)
from prl.geometry import rot_x, rot_z
from prl.shapes import CAP_CENTER_HEIGHT, unscrew_object_mesh, unscrew_tool_mesh

Range = tuple[float, float]

LYING_AXIS_HEIGHT = 0.20
"""Height (m) of a lying bottle's axis above the table (a bottle on a rack; lower, the lid plan's rotation turned
the lid less: ``PRLUnscrewMixedEnv``)."""


def lying_rotation(yaw_deg: float) -> np.ndarray:
    """The holder's rotation of a bottle lying on its side with its cap pointing along ``yaw_deg`` (deg about
    world Z from +X). The upright holder's frame (Z the axis, up) is turned -90 deg about its axis, then -90 deg
    about X (the axis onto +Y), then about Z onto the yaw. The cap's frame turns with it, and with it the hand's
    grasp (the executor places the palm in the cap's frame): the grasp that meets an upright cap from above with
    the fingers along world -Y meets the lying cap's end face with the palm vertical, the fingers horizontal and
    across the bottle's axis (along +X for the lid towards -Y), the thumb up."""
    return rot_z(np.deg2rad(yaw_deg - 90.0)) @ rot_x(-np.pi / 2) @ rot_z(-np.pi / 2)


def cradle_box(params: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """(centre, half extents) of a lying bottle's cradle in the object frame (origin at the cap's seat, Z along
    the axis to the cap; the world's down is the frame's -X, whatever the yaw): a block from the table up into
    the lower part of the body."""
    rb, hb, hh = float(params["body_radius"]), float(params["body_height"]), float(params["cap_half_height"])
    seat = CAP_CENTER_HEIGHT - hh
    top = 0.6 * rb
    return (np.array([-(top + LYING_AXIS_HEIGHT) / 2, 0.0, hb / 2 - seat]),
            np.array([(LYING_AXIS_HEIGHT - top) / 2, 0.7 * rb, 0.4 * hb]))


def unscrew_mixed_object_mesh(params: dict[str, float]) -> trimesh.Trimesh:
    """The bottle in the object frame (``prl.shapes.unscrew_object_mesh``), and under a lying one
    (``axis_tilt_deg`` 90) its cradle (``cradle_box``)."""
    mesh = unscrew_object_mesh(params)
    if float(params.get("axis_tilt_deg", 0.0)) == 0.0:
        return mesh
    center, half = cradle_box(params)
    box = trimesh.creation.box(extents=2 * half)
    box.apply_translation(center)
    return trimesh.util.concatenate([mesh, box])


@dataclass(frozen=True)
class CapFamily:
    """The ranges one family of caps and bottles is drawn from (metres, N m). The bottle's body is either drawn
    from ``body_height`` or ends ``shoulder_gap`` below the cap's seat (exactly one of the two is given)."""

    name: str
    cap_radius: Range
    breakaway_torque: Range
    body_radius: Range
    body_height: Range | None = None
    shoulder_gap: Range | None = None
    cap_half_height: Range = CAP_HALF_HEIGHT_RANGE
    cap_friction: Range = CAP_FRICTION_RANGE
    lying_yaw_deg: Range | None = None
    """None: the bottle stands upright in its holder. A range: the bottle lies on its side in a cradle, its axis
    horizontal at ``LYING_AXIS_HEIGHT``, the cap pointing along the world direction of this yaw (deg about Z from
    +X; 270 = -Y)."""

    def __post_init__(self) -> None:
        for field in ("cap_radius", "breakaway_torque", "body_radius", "body_height", "shoulder_gap",
                      "cap_half_height", "cap_friction", "lying_yaw_deg"):
            value = getattr(self, field)
            if value is None:
                continue
            ok = isinstance(value, tuple) and len(value) == 2 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            if not ok or not 0 < value[0] <= value[1]:
                raise ValueError(f"cap family {self.name!r}: {field} must be a range (low, high) with "
                                 f"0 < low <= high, got {value!r}")
        if (self.body_height is None) == (self.shoulder_gap is None):
            raise ValueError(f"cap family {self.name!r}: give exactly one of body_height and shoulder_gap, got "
                             f"body_height={self.body_height!r}, shoulder_gap={self.shoulder_gap!r}")


FLASK = CapFamily(
    name="flask", cap_radius=(0.014, 0.017), breakaway_torque=(0.25, 0.40), body_radius=(0.050, 0.060),
    shoulder_gap=(0.003, 0.006), cap_half_height=(0.008, 0.010),
)
"""Family 0: a small, short screw cap (2.8-3.4 cm across, 1.6-2.0 cm tall, 0.25-0.40 N m to break away) on a
wide flask (body radius 5-6 cm) whose shoulder lies 3-6 mm under the cap. Fingers that reach round and below the
cap (a medium wrap, flat extended fingers) land on the shoulder; the precision disk's fingertips grip the cap's
side from above."""
WIDE_LID = CapFamily(
    name="wide_lid", cap_radius=(0.036, 0.042), breakaway_torque=(3.8, 4.2), body_radius=BODY_RADIUS_RANGE,
    body_height=BODY_HEIGHT_RANGE, cap_friction=(1.2, 1.5), cap_half_height=(0.009, 0.011),
    lying_yaw_deg=(265.0, 275.0),
)
"""Family 1: a wide, low, tight, knurled lid (7.2-8.4 cm across, 1.8-2.2 cm tall, 3.8-4.2 N m to break away: a
stuck jar lid; side friction 1.2-1.5) on the base task's bottle, which lies on its side in a cradle (since
2026-12-06), its axis horizontal 20 cm above the table and its lid pointing towards -Y (yaw 265-275 deg). The
precision disk's fingertips slip on the lid; a medium wrap (the palm on the lid's face, the fingers round its rim)
holds the torque. The world-fixed arm translations of a4 act on it otherwise than on an upright cap: a drag along
Y pushes along its axis, and a drag along +X, which is the hand's drag along its own fingers here, rolls it
clockwise (``PRLUnscrewMixedEnv``)."""


@register_env("PRL-UnscrewMixed-v1", max_episode_steps=150)
class PRLUnscrewMixedEnv(MixedFamilies, PRLUnscrewEnv):
    """**Task Description:**
    The unscrew task (``PRL-Unscrew-v1``: grip a cap and turn it open; the same bottle in its fixed holder, the
    same thread drive with a breakaway torque, the same knurled side and smooth top) on scenes of two families,
    drawn from the scene's seed, whose physics needs different plans:

    - family 0, ``flask``: upright, a small short cap, radius 1.4-1.7 cm, half-height 0.8-1.0 cm, breakaway
      torque 0.25-0.40 N m, on a wide body (radius 5-6 cm) whose shoulder ends 3-6 mm below the cap's seat. A
      medium wrap or flat extended fingers reach round and below the cap and land on the shoulder; the precision
      disk's fingertips grip the cap's side from above. Plan: ``(0, 3, 2, 3, 5, 1)``, the base task's expert
      (precision disk, anchor 2, arm rotation about the palm).
    - family 1, ``wide_lid``: a wide tight lid, radius 3.6-4.2 cm, half-height 0.9-1.1 cm, side friction 1.2-1.5,
      breakaway torque 3.8-4.2 N m, on the base task's bottle (body radius 2.2-2.8 cm, height 3.5-4.5 cm) **lying
      on its side** in a cradle (a static block under the body): the axis horizontal at ``LYING_AXIS_HEIGHT`` =
      20 cm, the lid pointing along yaw 265-275 deg (towards -Y). The cap's frame is the upright one turned with
      the holder (``lying_rotation``), so the executor's grasp meets the lid's end face with the palm vertical
      and the fingers along +X; the precision disk's fingertips slip on the rim under that torque, a medium wrap
      holds it. Plan: ``(4, 3, 4, 0, 5, 1)`` (tilt -20 deg, anchor 4, medium wrap, arm rotation about the palm:
      a rotation about the palm normal, which is the lid's axis whatever way the bottle lies).

    **Why a drag opens flasks and not the lying lids.** A hand gripping a cap's knurled rim and translated
    sideways rolls the cap (friction on the rim, off the axis); the arm's translations (a4 = arm_linear_x/y/z)
    are along the world's axes, each with its "+" sign (no place stage). On the upright flask the drag along +Y
    of ``(1, 1, 1, 0, 3, 0)`` (medium wrap, anchor 1, twist -20 deg) opened the caps of both families of the
    previous design, 22 of 30 unseen scenes. On the lying lid the drag along Y pushes along the lid's axis (no
    moment about it); the drag along +X is, in the hand's frame, the upright drag along -Y, and rolls the lid
    clockwise (tightening); only the drag along Z crosses the axis the way the upright drag along X does. The
    rotation about the palm normal is the same turn in the lid's frame either way. Measured 2026-12-06 on 10
    scenes of each family from seed 33000 (``python -m envs.family_probe --task unscrew_mixed --family <f>
    --plans ... --scenes 10 --first-seed 33000``), flasks / lying lids: ``(1, 1, 1, 0, 3, 0)`` 6/10 / 0/10,
    ``(1, 1, 3, 0, 3, 3)`` 8/10 / 0/10, along X ``(1, 1, 1, 0, 2, 0)`` 0/10 / 0/10 (mean turn -1 deg on the lids),
    ``(1, 5, 1, 0, 2, 0)`` 0/10 / 0/10 (-11 deg), along Z ``(0, 3, 2, 0, 4, 1)`` 0/10 / 2/10; the lid plan 10/10
    lids. With the hand's roll about the lying axis the other way (fingers along -X) the drag along +X is the
    upright drag along +Y and opened 7/10 lids (the axis then 16 cm high): the drag's failure along X rests on
    which side of the axis the hand grips, as on an upright cap. The axis lies 20 cm high because lower the lid
    plan turned less (9 cm: 6/10, 12 cm: 7/10, 16 cm: 10/10 at a mean 26 deg, 20 cm: 10/10 at 33 deg). Under the
    search (``python -m envs.variant_search --tasks unscrew_mixed``, official size, 50 check scenes) the best
    fixed plan is the lid plan, 26/50 = 0.52; the experts 25/25 and 25/25 on their families. More numbers:
    ``docs/guide/tasks.md``, "Unscrewing, mixed".

    The family is ``scene_params["family"]``; x sees it through the sizes (the cap's radius in the tool's point
    cloud, the body's radius and height in the object's, rebuilt by ``prl.shapes.scene_meshes`` with this
    class's builders: the base task's cap, the base task's bottle and, under a lying one, its cradle) and
    through the poses (x_manip's tool and object poses: a lying bottle's object frame has its Z horizontal),
    never through the family index. The executor, the RN and the LN do not read it.

    **Randomizations:**
    - the family: 0 or 1 with probability 1/2 each, the first value drawn from the scene's seeded generator
    - then, from the family's ranges (scaled by ``randomization`` as the base task's): cap radius, cap
      half-height, cap side friction (family 0 in [0.9, 1.4], family 1 in [1.2, 1.5]), breakaway torque, body
      radius, and the body's height (family 1) or the shoulder's gap under the cap's seat (family 0: the body's
      height is then 9 cm - the cap's half-height - the gap)
    - bottle position +-2 cm in x, y (as the base task; for a lying bottle, the lid's centre), then for a lying
      bottle the lid's yaw in [265, 275] deg (``scene_params["axis_tilt_deg"]`` 0 or 90, ``"axis_yaw_deg"``)

    **Success Conditions:**
    - the base task's, unchanged: the cap turned more than 8 deg counter-clockwise seen from outside the cap
      (from above for an upright bottle; the joint turns with its holder) during the plan's motion, and at the
      end at least two hand links other than the palm press on the cap's side; reward = that turn in degrees
    - fail: NaN in the simulation
    """

    task_name = "unscrew_mixed"
    families: ClassVar[tuple[CapFamily, ...]] = (FLASK, WIDE_LID)
    family_expert_plans: ClassVar[dict[int, tuple[int, ...]]] = {0: (0, 3, 2, 3, 5, 1), 1: (4, 3, 4, 0, 5, 1)}
    """Family 0 (flask): precision disk at anchor 2, no tilt (the base task's expert); family 1 (lying wide lid):
    medium wrap at anchor 4, the palm tilted -20 deg about X; both turn with the arm about the palm
    (a4 = arm_rotate_palm)."""
    expert_plan = family_expert_plans[0]

    tool_mesh = staticmethod(unscrew_tool_mesh)
    object_mesh = staticmethod(unscrew_mixed_object_mesh)

    @classmethod
    def check_families(cls) -> None:
        """The mixin's checks (``MixedFamilies.check_families``), and every family a ``CapFamily``."""
        super().check_families()
        for i, spec in enumerate(cls.families):
            if not isinstance(spec, CapFamily):
                raise ValueError(f"{cls.__name__}.families[{i}] must be a CapFamily, got {spec!r}")  # noqa: TRY004

    # ------------------------------------------------------------------ scene
    def _load_scene(self, options: dict) -> None:
        rng = self._scene_rng()
        family = self.draw_family(rng)
        spec: CapFamily = self.family_spec(family)
        u = partial(self._uniform, rng)
        self.scene_params = params = {"family": family}
        params.update({
            "cap_radius": u(*spec.cap_radius),
            "cap_half_height": u(*spec.cap_half_height),
            "cap_friction": u(*spec.cap_friction),
            "breakaway_torque": u(*spec.breakaway_torque),
            "body_radius": u(*spec.body_radius),
        })
        if spec.shoulder_gap is not None:
            params["body_height"] = CAP_CENTER_HEIGHT - params["cap_half_height"] - u(*spec.shoulder_gap)
        else:
            params["body_height"] = u(*spec.body_height)
        params["bottle_x"] = BOTTLE_XY[0] + u(-BOTTLE_XY_RANGE, BOTTLE_XY_RANGE)
        params["bottle_y"] = BOTTLE_XY[1] + u(-BOTTLE_XY_RANGE, BOTTLE_XY_RANGE)
        if spec.lying_yaw_deg is None:
            params["axis_tilt_deg"], params["axis_yaw_deg"] = 0.0, 0.0
        else:
            params["axis_tilt_deg"], params["axis_yaw_deg"] = 90.0, u(*spec.lying_yaw_deg)
        self._build_table()
        self._build_bottle(params)
        self._motion_start_deg = 0.0  # also before the first episode (ManiSkill reads the state at construction)

    def _holder_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(position, rotation) of the bottle's holder (its root link: the body's base, Z along the axis)."""
        p = self.scene_params
        if p["axis_tilt_deg"] == 0.0:
            return np.array([p["bottle_x"], p["bottle_y"], 0.0]), np.eye(3)
        rotation = lying_rotation(p["axis_yaw_deg"])
        cap = np.array([p["bottle_x"], p["bottle_y"], LYING_AXIS_HEIGHT])
        return cap - rotation[:, 2] * CAP_CENTER_HEIGHT, rotation

    def _build_bottle(self, params: dict[str, float]) -> None:
        """The base task's bottle; a lying one is then turned onto its side (its holder's pose, also the pose
        the scene resets it to) over a static cradle."""
        super()._build_bottle(params)
        if params["axis_tilt_deg"] == 0.0:
            return
        position, rotation = self._holder_pose()
        pose = pose_from_matrix(position, rotation)
        self.bottle.initial_pose = Pose.create(pose)
        self.bottle.set_pose(Pose.create(pose))
        center, half = cradle_box(params)
        seat = position + rotation @ np.array([0.0, 0.0, self._seat_height()])
        self.cradle = self._build_static_box("cradle", seat + rotation @ center, half, rotation,
                                            (0.55, 0.45, 0.3, 1.0))

    def object_frame_world(self) -> tuple[np.ndarray, np.ndarray]:
        """The bottle's frame: origin at the cap's seat on the neck, Z along the bottle's axis towards the cap
        (up for an upright bottle, horizontal for a lying one)."""
        position, rotation = self._holder_pose()
        return position + rotation @ np.array([0.0, 0.0, self._seat_height()]), rotation
