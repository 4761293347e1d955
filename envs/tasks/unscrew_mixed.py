"""PRL unscrewing task, mixed variant (issue #26): a small cap on a wide-shouldered flask, or a wide tight lid."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import ClassVar

from mani_skill.utils.registration import register_env

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
from prl.shapes import CAP_CENTER_HEIGHT

Range = tuple[float, float]


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

    def __post_init__(self) -> None:
        for field in ("cap_radius", "breakaway_torque", "body_radius", "body_height", "shoulder_gap",
                      "cap_half_height", "cap_friction"):
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
)
"""Family 1: a wide, low, tight, knurled lid (7.2-8.4 cm across, 1.8-2.2 cm tall, 3.8-4.2 N m to break away: a
stuck jar lid; side friction 1.2-1.5) on the base task's bottle. The precision disk's fingertips slip on it, tilted
or not; a medium wrap (the palm on the lid, the fingers round its rim) holds that torque, untilted or tilted
(ranges of 2026-12-05: see ``docs/guide/tasks.md``)."""


@register_env("PRL-UnscrewMixed-v1", max_episode_steps=150)
class PRLUnscrewMixedEnv(MixedFamilies, PRLUnscrewEnv):
    """**Task Description:**
    The unscrew task (``PRL-Unscrew-v1``: grip a cap and turn it open; the same bottle in its fixed holder, the
    same thread drive with a breakaway torque, the same knurled side and smooth top) on scenes of two families,
    drawn from the scene's seed, whose physics needs different plans:

    - family 0, ``flask``: a small short cap, radius 1.4-1.7 cm, half-height 0.8-1.0 cm, breakaway torque
      0.25-0.40 N m, on a wide body (radius 5-6 cm) whose shoulder ends 3-6 mm below the cap's seat. A medium
      wrap or flat extended fingers reach round and below the cap and land on the shoulder (a tilted wrap's palm
      may still turn the cap by its rim, with no finger on its side: not gripped); the precision disk's
      fingertips grip the cap's side from above. Plan: ``(0, 3, 2, 3, 5, 1)``, the base task's expert
      (precision disk, anchor 2, arm rotation about the palm).
    - family 1, ``wide_lid``: a wide tight lid, radius 3.6-4.2 cm, half-height 0.9-1.1 cm, side friction 1.2-1.5,
      breakaway torque 3.8-4.2 N m, on the base task's bottle (body radius 2.2-2.8 cm, height 3.5-4.5 cm). The
      precision disk's fingertips slip on the rim under that torque; a medium wrap holds it, the palm untilted
      (``(0, 3, 2, 0, 5, 1)``) or tilted. Plan: ``(4, 3, 4, 0, 5, 1)`` (tilt -20 deg, anchor 4, medium wrap, arm
      rotation about the palm).

    Measured: each family's plan on 30 scenes of each family, the trial scenes' oracle and fixed plans
    (``python -m envs.families --task unscrew_mixed --scenes 50``), uniform plans (``--uniform``), and how these
    ranges were chosen: ``docs/guide/tasks.md``, "Unscrewing, mixed" (numbers there, so that a new measurement does not
    change this module and with it the task's code version).

    The family is ``scene_params["family"]``; x sees it through the sizes (the cap's radius in the tool's point
    cloud, the body's radius and height in the object's, rebuilt by ``prl.shapes.scene_meshes`` with the base
    task's builders), never through the family index. The executor, the RN and the LN do not read it.

    **Randomizations:**
    - the family: 0 or 1 with probability 1/2 each, the first value drawn from the scene's seeded generator
    - then, from the family's ranges (scaled by ``randomization`` as the base task's): cap radius, cap
      half-height, cap side friction (family 0 in [0.9, 1.4], family 1 in [1.2, 1.5]), breakaway torque, body
      radius, and the body's height (family 1) or the shoulder's gap under the cap's seat (family 0: the body's
      height is then 9 cm - the cap's half-height - the gap)
    - bottle position +-2 cm in x, y (as the base task)

    **Success Conditions:**
    - the base task's, unchanged: the cap turned more than 8 deg counter-clockwise seen from above during the
      plan's motion, and at the end at least two hand links other than the palm press on the cap's side;
      reward = that turn in degrees
    - fail: NaN in the simulation
    """

    task_name = "unscrew_mixed"
    families: ClassVar[tuple[CapFamily, ...]] = (FLASK, WIDE_LID)
    family_expert_plans: ClassVar[dict[int, tuple[int, ...]]] = {0: (0, 3, 2, 3, 5, 1), 1: (4, 3, 4, 0, 5, 1)}
    """Family 0 (flask): precision disk at anchor 2, no tilt (the base task's expert); family 1 (wide lid): medium
    wrap at anchor 4, the palm tilted -20 deg about X; both turn with the arm about the palm (a4 = arm_rotate_palm)."""
    expert_plan = family_expert_plans[0]

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
        self._build_table()
        self._build_bottle(params)
        self._motion_start_deg = 0.0  # also before the first episode (ManiSkill reads the state at construction)
