"""PRL tweezing task, mixed variant (issue #26): the base task's tweezers, or long tweezers holding the cube deep
between their arms."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import ClassVar

import numpy as np
from mani_skill.utils.registration import register_env

from envs.tasks.mixed import MixedFamilies
from envs.tasks.tweeze import (
    ARM_LENGTH_RANGE,
    CUBE_FRICTION_RANGE,
    CUBE_MASS_RANGE,
    CUBE_OFFSET_RANGE,
    CUBE_SIZE_RANGE,
    PLATFORM_FROM,
    SPRING_STIFFNESS_RANGE,
    TIP_GAP_RANGE,
    TWEEZERS_FRICTION_RANGE,
    TWEEZERS_XY,
    TWEEZERS_XY_RANGE,
    TWEEZERS_YAW_RANGE,
    PRLTweezeEnv,
)
from prl.shapes import TWEEZERS_ARM_THICKNESS, tweezers_arm_angle

Range = tuple[float, float]

CUBE_REST_MARGIN = 0.004
"""The tips' block, when the cube lies before it, reaches back this far (m) under the cube's near face."""


@dataclass(frozen=True)
class TweezeFamily:
    """The ranges one family of tweezers and cubes is drawn from (metres, N m/rad, kilograms). ``cube_along`` is
    where the cube lies along the arms from the base task's spot (its far face ``CUBE_INSIDE`` inside the tips):
    0 there, negative deeper between the arms, towards the hinge."""

    name: str
    arm_length: Range = ARM_LENGTH_RANGE
    tip_gap: Range = TIP_GAP_RANGE
    cube_size: Range = CUBE_SIZE_RANGE
    cube_along: Range = (-CUBE_OFFSET_RANGE, CUBE_OFFSET_RANGE)
    cube_mass: Range = CUBE_MASS_RANGE
    spring_stiffness: Range = SPRING_STIFFNESS_RANGE

    def __post_init__(self) -> None:
        for field in ("arm_length", "tip_gap", "cube_size", "cube_along", "cube_mass", "spring_stiffness"):
            value = getattr(self, field)
            ok = isinstance(value, tuple) and len(value) == 2 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            positive = field != "cube_along"
            if not ok or not value[0] <= value[1] or (positive and not value[0] > 0):
                need = "0 < low <= high" if positive else "low <= high"
                raise ValueError(f"tweeze family {self.name!r}: {field} must be a range (low, high) with {need}, "
                                 f"got {value!r}")


TIPS = TweezeFamily(name="tips")
"""Family 0: the base task's scenes (``PRL-Tweeze-v1``'s ranges): tweezers 15-17 cm long, the cube (2.0-2.5 cm)
between the tips, its far face 8 mm inside them."""
LONG_DEEP = TweezeFamily(
    name="long_deep", arm_length=(0.25, 0.27), tip_gap=(0.048, 0.052), cube_size=(0.024, 0.027),
    cube_along=(-0.07, -0.06),
)
"""Family 1: long tweezers (25-27 cm, tips 4.8-5.2 cm apart) holding a larger cube (2.4-2.7 cm) deep between the
arms, 6-7 cm further towards the hinge than in family 0 (on the tips' block, which then reaches back under it)."""


@register_env("PRL-TweezeMixed-v1", max_episode_steps=150)
class PRLTweezeMixedEnv(MixedFamilies, PRLTweezeEnv):
    """**Task Description:**
    The tweeze task (``PRL-Tweeze-v1``: squeeze a pair of tweezers shut on a small cube and lift it with their
    tips; the same spring hinge, cradle, rack and tips' block, the same executor stages and cube watch) on scenes
    of two families, drawn from the scene's seed, whose physics needs different plans. The executor puts the palm
    across the arms over T_gv (the arms between 40% and 60% of their length), its thumb side towards the butt and
    its little-finger side towards the tips and the cube; a0 tilts it about the arms, a1 about the axis across
    them, and the anchor's column (a2 even: on the thumb side, odd: on the little-finger side) shifts the whole
    hand 3.2 cm along the arms:

    - family 0, ``tips``: the base task's scenes, arms 15-17 cm long, tips 4.0-4.6 cm apart, the cube (edge
      2.0-2.5 cm) between the tips. A pinch must land well out towards the tips to shut them on the cube: the
      hand shifted towards the butt (odd anchors) pinches too near the hinge and lifts the tweezers with their
      tips open. Plan: ``(2, 1, 4, 2, 6, 1)``, the base task's expert (tilt -10 deg about X, -20 deg about Z,
      anchor 4, palmar pinch, finger squeeze).
    - family 1, ``long_deep``: arms 25-27 cm long, tips 4.8-5.2 cm apart, a cube of edge 2.4-2.7 cm lying 6-7 cm
      deeper between the arms (about 17-19 cm from the hinge), on the tips' block, which reaches back under it.
      The cube now lies under the little-finger side of a hand at anchor 4: the palm or the little finger presses
      on it (a touched cube never counts). A hand shifted towards the butt (anchor 5) clears it, and on these
      long arms its pinch is still far enough from the hinge to shut them. Plan: ``(2, 2, 5, 3, 6, 1)`` (tilt
      -10 deg about X and about Z, anchor 5, precision disk, finger squeeze).

    Measured (2026-12-03, 30 scenes of each family, seeds 20000-20062): each family's plan 30/30 on its own
    family; the family 1 plan 0/30 on family 0, the family 0 plan 4/30 on family 1 (on the others the palm or the
    little finger pressed on the deep cube, or the tips did not shut); uniform plans 2/60; on the pipeline's trial
    seeds 0-64 (25 of each family) 25/25 and 25/25, crossed 0/25 and 3/25; ``python -m envs.trials --task
    tweeze_mixed --scenes 50``: expert (family 0's plan) 23/50, prior 5/50, uniform 6/50.

    The family is ``scene_params["family"]``; x sees it through the sizes (the arms' length and the tips' gap in
    the tweezers' point cloud, the cube's edge in the object's, rebuilt by ``prl.shapes.scene_meshes`` with the
    base task's builders) and through the poses x_manip records (the cube 6-7 cm deeper between the arms relative
    to the tweezers' pose), never through the family index. The executor, the RN and the LN do not read it.

    **Randomizations:**
    - the family: 0 or 1 with probability 1/2 each, the first value drawn from the scene's seeded generator
    - then, from the family's ranges (scaled by ``randomization`` as the base task's): arm length, open tip gap,
      spring stiffness in [1, 2] N m/rad, tweezers friction in [0.8, 1.2], cube edge, cube mass in [4, 15] g,
      cube friction in [0.6, 1.0], tweezers position +-2 cm in x, y and yaw +-10 deg, the cube's spot along the
      arms (family 0: +-3 mm; family 1: 6-7 cm deeper) and across them (+-3 mm, nearer arm a as the base task)

    **Success Conditions:**
    - the base task's, unchanged: the cube's lowest point more than 10 cm above the block it rested on at the end,
      and no hand link pressed on it in any physics frame of the episode; reward = the lift in cm
    - fail: the tweezers fell off the table or the simulation produced NaN
    """

    task_name = "tweeze_mixed"
    families: ClassVar[tuple[TweezeFamily, ...]] = (TIPS, LONG_DEEP)
    family_expert_plans: ClassVar[dict[int, tuple[int, ...]]] = {0: (2, 1, 4, 2, 6, 1), 1: (2, 2, 5, 3, 6, 1)}
    """Family 0 (tips): palmar pinch at anchor 4 (the hand towards the tips), the base task's expert; family 1
    (long_deep): precision disk at anchor 5 (the hand 3.2 cm towards the butt, clear of the deep cube); both tilt
    -10 deg about X and squeeze the fingers (a4 = finger_squeeze); a5 is not acted on (no place stage)."""
    expert_plan = family_expert_plans[0]

    @classmethod
    def check_families(cls) -> None:
        """The mixin's checks (``MixedFamilies.check_families``), and every family a ``TweezeFamily``."""
        super().check_families()
        for i, spec in enumerate(cls.families):
            if not isinstance(spec, TweezeFamily):
                raise ValueError(f"{cls.__name__}.families[{i}] must be a TweezeFamily, got {spec!r}")  # noqa: TRY004

    # ------------------------------------------------------------------ scene
    def _load_scene(self, options: dict) -> None:
        self._hand_touched_cube: list[str] = []  # also before the first episode (the state is read at construction)
        rng = self._scene_rng()
        family = self.draw_family(rng)
        spec: TweezeFamily = self.family_spec(family)
        u = partial(self._uniform, rng)
        self.scene_params = params = {"family": family}
        params.update({  # the base task's values, in its order, from the family's ranges
            "arm_length": u(*spec.arm_length),
            "tip_gap": u(*spec.tip_gap),
            "spring_stiffness": u(*spec.spring_stiffness),
            "tweezers_friction": u(*TWEEZERS_FRICTION_RANGE),
            "cube_size": u(*spec.cube_size),
            "cube_mass": u(*spec.cube_mass),
            "cube_friction": u(*CUBE_FRICTION_RANGE),
            "tweezers_x": TWEEZERS_XY[0] + u(-TWEEZERS_XY_RANGE, TWEEZERS_XY_RANGE),
            "tweezers_y": TWEEZERS_XY[1] + u(-TWEEZERS_XY_RANGE, TWEEZERS_XY_RANGE),
            "tweezers_yaw": u(-TWEEZERS_YAW_RANGE, TWEEZERS_YAW_RANGE),
            "cube_along": u(*spec.cube_along),
            "cube_across": u(-CUBE_OFFSET_RANGE, CUBE_OFFSET_RANGE),
        })
        self._build_table()
        self._build_tweezers(params)
        self._build_rack(params)
        self._build_cube(params)

    def _build_rack(self, params: dict[str, float]) -> None:
        """The base task's rack; when the cube's centre lies before the tips' block (family 1's deep cube), a block
        of the same height and width runs from ``CUBE_REST_MARGIN`` behind the cube's near face to the tips' block,
        under the cube and the arms there (it carries them as the tips' block does). Family 0's cube lies on the
        tips' block: its rack is the base task's."""
        super()._build_rack(params)
        length = params["arm_length"]
        origin, rotation = self._rest_frame()
        center, _ = self._cube_rest()
        along = float((rotation.T @ (center - origin))[0])
        lo, hi = along - params["cube_size"] / 2 - CUBE_REST_MARGIN, PLATFORM_FROM * length
        if along >= hi:
            return
        top = self.rest_surface()
        mid = origin + rotation @ np.array([(lo + hi) / 2, 0.0, 0.0])
        across = length * np.sin(tweezers_arm_angle(length, params["tip_gap"])) + 2 * TWEEZERS_ARM_THICKNESS + 0.01
        self._build_static_box("cube_rest", np.array([mid[0], mid[1], top / 2]),
                               np.array([(hi - lo) / 2 + 0.001, across, top / 2]), params["tweezers_yaw"],
                               (0.3, 0.3, 0.35, 1))
