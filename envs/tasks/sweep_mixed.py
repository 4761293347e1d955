"""PRL sweeping task, mixed variant (issue #26): debris to be swept along the arm's X, or across it along Y."""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import ClassVar

import numpy as np
from mani_skill.utils.registration import register_env

from envs.tasks.mixed import MixedFamilies
from envs.tasks.sweep import (
    BROOM_FRICTION_RANGE,
    BROOM_MASS_RANGE,
    BROOM_REST_XY,
    BROOM_REST_XY_RANGE,
    BROOM_REST_YAW_RANGE,
    CUBE_COUNT_RANGE,
    CUBE_FRICTION_RANGE,
    CUBE_MASS_RANGE,
    CUBE_YAW_RANGE,
    SIZE_SCALE_RANGE,
    SLOT_COLS_Y,
    SLOT_JITTER,
    SLOT_ROWS_X,
    SWEEP_LINE_XY,
    SWEEP_LINE_XY_RANGE,
    ZONE_DEPTH,
    ZONE_HALF_WIDTH,
    ZONE_OFFSET_RANGE,
    PRLSweepEnv,
)
from prl.geometry import rot_z
from prl.shapes import (
    BROOM_HANDLE_HALF_LENGTH,
    BROOM_HANDLE_RADIUS,
    BROOM_HEAD_HALF,
    DEBRIS_CUBE_SIZE_RANGE,
    SWEEP_CLEARANCE,
)

Range = tuple[float, float]
XY = tuple[float, float]

QUARTER_TURNS_DEG = (0, 90, 180, 270)
"""The turns a family's layout may have about the vertical: quarter turns, so the zone stays a world-axis-aligned
rectangle (``zone_box``)."""


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and bool(np.isfinite(value))


@dataclass(frozen=True)
class SweepFamily:
    """One family's layout (metres, degrees) and debris ranges (kg, friction).

    The family's whole layout is the base task's turned by ``turn_deg`` about the vertical: the broom's rack (its
    handle's middle at ``rack_xy``, the base yaw plus ``turn_deg``), and the sweep frame (origin on the sweep line's
    centre ``line_xy``, X towards the zone) with the debris patch behind the line and the zone beyond it. The slots,
    the zone's size and the randomisation ranges are the base task's, in the sweep frame."""

    name: str
    turn_deg: int
    rack_xy: XY
    line_xy: XY
    cube_mass: Range = CUBE_MASS_RANGE
    cube_friction: Range = CUBE_FRICTION_RANGE

    def __post_init__(self) -> None:
        if isinstance(self.turn_deg, bool) or self.turn_deg not in QUARTER_TURNS_DEG:
            raise ValueError(f"sweep family {self.name!r}: turn_deg must be one of {QUARTER_TURNS_DEG}, "
                             f"got {self.turn_deg!r}")
        for field in ("rack_xy", "line_xy"):
            value = getattr(self, field)
            if not (isinstance(value, tuple) and len(value) == 2 and all(_is_number(v) for v in value)):
                raise ValueError(f"sweep family {self.name!r}: {field} must be a point (x, y), got {value!r}")
        for field in ("cube_mass", "cube_friction"):
            value = getattr(self, field)
            ok = isinstance(value, tuple) and len(value) == 2 and all(_is_number(v) for v in value)
            if not ok or not 0 < value[0] <= value[1]:
                raise ValueError(f"sweep family {self.name!r}: {field} must be a range (low, high) with "
                                 f"0 < low <= high, got {value!r}")

    @property
    def turn(self) -> float:
        """``turn_deg`` in radians."""
        return float(np.deg2rad(self.turn_deg))


ALONG = SweepFamily(name="along", turn_deg=0, rack_xy=BROOM_REST_XY, line_xy=SWEEP_LINE_XY)
"""Family 0: the base task's layout. The broom lies along the arm's X on its rack; the debris lie behind a sweep line
across X and the zone beyond it along +X: the head's wide face pushes along the arm's X."""
ACROSS = SweepFamily(name="across", turn_deg=90, rack_xy=BROOM_REST_XY, line_xy=(-0.27, -0.05))
"""Family 1: the base task's layout turned a quarter turn (+90 deg) about the vertical through the rack's centre.
The broom lies along Y (its head towards -Y), the debris lie behind a sweep line across Y and the zone beyond it
along +Y: standing head-down, the broom's wide face looks along Y, and the sweep must go along the arm's Y (along
the arm's X the head runs edge-on along the sweep line, beside the patch)."""


@register_env("PRL-SweepMixed-v1", max_episode_steps=150)
class PRLSweepMixedEnv(MixedFamilies, PRLSweepEnv):
    """**Task Description:**
    The sweep task (``PRL-Sweep-v1``: pick up the broom leaning on its rack, stand it head-down and sweep debris
    cubes into a zone; the same broom, cubes, slots, zone and success rule) on scenes of two families, drawn from
    the scene's seed, whose physics needs different plans. The arm's translations are along the world's fixed X
    and Y, so which one pushes the broom's wide face onto the debris depends on how the scene lies:

    - family 0, ``along``: the base task's layout: the broom along X on its rack at (-5, -10) cm, the debris patch
      behind the sweep line at (0, 12) cm, the zone beyond it along +X. Plan: ``(0, 3, 2, 0, 2, 0)``, the base
      task's expert (no tilt, no twist, anchor 2, medium wrap, arm linear along X, T_fv's X vertical).
    - family 1, ``across``: the same layout turned +90 deg about the vertical through the rack: the broom along Y
      (head towards -Y), the sweep line at (-27, -5) cm, the debris behind it along -Y and the zone beyond it
      along +Y. Standing head-down the broom's wide face looks along Y; a push along X runs the head edge-on
      along the sweep line, beside the patch, and moves no cube (so does a push along Y on family 0's scenes).
      Plan: ``(0, 3, 2, 0, 3, 0)`` (the same grasp and stance, arm linear along Y).

    Measured (2026-12-03, 30 scenes of each family, seeds 20000-20062): each family's plan 30/30 on its own
    family, 0/30 on the other's (no cube in the zone); uniform plans 0/60; on the pipeline's trial seeds 0-49 (20 of
    family 0, 30 of family 1) 20/20 and 30/30, crossed 0/20 and 0/30, so the best single plan there is family 1's,
    30/50; ``python -m envs.trials --task sweep_mixed --scenes 50``: expert 20/50, prior 10/50 (all 10 on family 0's
    28 scenes: the prior gives arm_linear_y 0.10, arm_linear_x 0.60; prior plans with a4 set to the family's motion
    succeed 13/30 on family 0 and 10/30 on family 1), uniform 0/50; ``python -m envs.families --task sweep_mixed
    --scenes 50``: family oracle 50/50, best single fixed plan (family 1's expert) 30/50.

    The family is ``scene_params["family"]``; x sees it through the layout: the debris patch (2 rows x 4 columns)
    lies across X or across Y in the object's point cloud (rebuilt by ``prl.shapes.scene_meshes`` with the base
    task's builders, in world axes), and x_manip records the broom's pose (its yaw differs by 90 deg) and the sweep
    frame's pose (X towards the zone), never the family index. The executor, the RN and the LN do not read it.

    **Randomizations:**
    - the family: 0 or 1 with probability 1/2 each, the first value drawn from the scene's seeded generator
    - then, as the base task (ranges scaled by ``randomization``): handle and head size factors in [0.9, 1.1],
      broom mass in [0.15, 0.30] kg, friction in [0.8, 1.4]; rack position +-2 cm in x, y about the family's and
      yaw +-8 deg about the family's (0 or 90 deg); sweep line +-2 cm in x, y about the family's; zone's near edge
      0-1 cm past the line; 6-8 cubes in the 2 x 4 slots (in the sweep frame), each 1.5-2 cm, 5-20 g, friction
      0.3-0.7, +-2 mm and +-15 deg about its slot

    **Success Conditions:**
    - the base task's, unchanged: more than 3 cube centres inside the zone at the end, each swept there by the
      broom (not pressed by a hand link, not pushed by a loose broom); every cube starts outside it
    - fail: the broom fell off the table or the simulation produced NaN
    - reward (dense) = the number of cubes in the zone
    """

    task_name = "sweep_mixed"
    families: ClassVar[tuple[SweepFamily, ...]] = (ALONG, ACROSS)
    family_expert_plans: ClassVar[dict[int, tuple[int, ...]]] = {0: (0, 3, 2, 0, 2, 0), 1: (0, 3, 2, 0, 3, 0)}
    """Family 0 (along): the base task's expert, the arm linear along X; family 1 (across): the same grasp and
    stance, the arm linear along Y (a4 = arm_linear_y)."""
    expert_plan = family_expert_plans[0]

    @classmethod
    def check_families(cls) -> None:
        """The mixin's checks (``MixedFamilies.check_families``), and every family a ``SweepFamily``."""
        super().check_families()
        for i, spec in enumerate(cls.families):
            if not isinstance(spec, SweepFamily):
                raise ValueError(f"{cls.__name__}.families[{i}] must be a SweepFamily, got {spec!r}")  # noqa: TRY004

    # ------------------------------------------------------------------ scene
    def _sample_params(self, rng: np.random.RandomState) -> dict[str, float]:
        """The family (first draw), then one episode's values as the base task draws them, about the family's
        layout: the rack's and the sweep line's nominal positions and the turn of both (``SweepFamily``)."""
        family = self.draw_family(rng)
        spec: SweepFamily = self.family_spec(family)
        u = partial(self._uniform, rng)
        handle_scale, head_scale = u(*SIZE_SCALE_RANGE), u(*SIZE_SCALE_RANGE)
        values: dict[str, float] = {
            "handle_radius": BROOM_HANDLE_RADIUS * handle_scale,
            "handle_half_length": BROOM_HANDLE_HALF_LENGTH * handle_scale,
            "head_half_x": BROOM_HEAD_HALF[0] * head_scale,
            "head_half_y": BROOM_HEAD_HALF[1] * head_scale,
            "head_half_z": BROOM_HEAD_HALF[2] * head_scale,
            "broom_mass": u(*BROOM_MASS_RANGE),
            "broom_friction": u(*BROOM_FRICTION_RANGE),
            "rack_x": spec.rack_xy[0] + u(-BROOM_REST_XY_RANGE, BROOM_REST_XY_RANGE),
            "rack_y": spec.rack_xy[1] + u(-BROOM_REST_XY_RANGE, BROOM_REST_XY_RANGE),
            "rack_yaw": spec.turn + u(-BROOM_REST_YAW_RANGE, BROOM_REST_YAW_RANGE),
            "line_x": spec.line_xy[0] + u(-SWEEP_LINE_XY_RANGE, SWEEP_LINE_XY_RANGE),
            "line_y": spec.line_xy[1] + u(-SWEEP_LINE_XY_RANGE, SWEEP_LINE_XY_RANGE),
            "zone_offset": u(*ZONE_OFFSET_RANGE),
            "sweep_yaw": spec.turn,
        }
        n_cubes = int(rng.randint(CUBE_COUNT_RANGE[0], CUBE_COUNT_RANGE[1] + 1))
        slots = rng.permutation(len(SLOT_ROWS_X) * len(SLOT_COLS_Y))[:n_cubes]
        values["n_cubes"] = n_cubes
        turn = rot_z(spec.turn)[:2, :2]
        line = np.array([values["line_x"], values["line_y"]])
        for i, slot in enumerate(sorted(int(s) for s in slots)):
            row, col = divmod(slot, len(SLOT_COLS_Y))
            local = np.array([SLOT_ROWS_X[row] + u(-SLOT_JITTER, SLOT_JITTER),
                              SLOT_COLS_Y[col] + u(-SLOT_JITTER, SLOT_JITTER)])
            values[f"cube{i}_x"], values[f"cube{i}_y"] = line + turn @ local
            values[f"cube{i}_yaw"] = u(-CUBE_YAW_RANGE, CUBE_YAW_RANGE)
            values[f"cube{i}_size"] = u(*DEBRIS_CUBE_SIZE_RANGE)
            values[f"cube{i}_mass"] = u(*spec.cube_mass)
            values[f"cube{i}_friction"] = u(*spec.cube_friction)
        # the family as an int (the interface of issue #26), first; read by no mesh builder, nor by x
        return {"family": family, **{key: float(value) for key, value in values.items()}}

    def zone_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The zone as (min (2,), max (2,)) world (x, y) corners: the base task's rectangle in the sweep frame (near
        edge ``zone_offset`` past the line along the frame's X, ``ZONE_DEPTH`` deep, ``2 ZONE_HALF_WIDTH`` wide),
        turned by the family's quarter turn (so it stays axis-aligned)."""
        p = self.scene_params
        x0 = p["zone_offset"]
        corners = np.array([[x0, -ZONE_HALF_WIDTH], [x0 + ZONE_DEPTH, ZONE_HALF_WIDTH]])
        world = corners @ rot_z(p["sweep_yaw"])[:2, :2].T + np.array([p["line_x"], p["line_y"]])
        return world.min(axis=0), world.max(axis=0)

    # ------------------------------------------------------------------ executor API
    def object_frame_world(self) -> tuple[np.ndarray, np.ndarray]:
        """Sweep frame: origin on the sweep line's centre, ``SWEEP_CLEARANCE`` above the table; X towards the zone
        (world +X turned by the family's quarter turn), Z up. Fixed in the world."""
        p = self.scene_params
        return np.array([p["line_x"], p["line_y"], SWEEP_CLEARANCE]), rot_z(p["sweep_yaw"])
