"""A toy task kept outside ``envs/tasks``: the worked example of ``docs/guide/add-a-task.md``.

**nudge**: the broom of the sweep stands on its head and pushes the debris along +X; success is *one* swept cube in
the zone (the sweep asks for more than three). It is a base task that reuses the sweep's scene by inheritance (its
own name has no underscore, so it is no variant of the sweep) and declares everything else the pipeline reads in
this one file: its name and environment id, its measure and unit, its mesh builders (the sweep's, its scenes are the
sweep's), the red team's evidence, and its catalogue entry (texts and prior), since ``assets/plb.yaml`` has none.
Importing this module registers it; no list elsewhere names it.
"""

from __future__ import annotations

from typing import Any, ClassVar

import torch
from mani_skill.utils.registration import register_env

from envs.tasks.sweep import PRLSweepEnv
from prl.plb import load_plb

ENV_ID = "PRL-ToyNudge-v1"


def _sweep_prior() -> dict[str, list[float]]:
    """The sweep's prior by dimension name: a broom task's plausible plans."""
    plb = load_plb()
    return {dim.name: [float(p) for p in probs] for dim, probs in zip(plb.dims, plb.prior("sweep"), strict=True)}


@register_env(ENV_ID, max_episode_steps=150)
class ToyNudgeEnv(PRLSweepEnv):
    """Push at least one debris cube into the zone with the broom (the sweep's scene and stages)."""

    task_name = "nudge"
    measure_key = "cubes_in_zone"
    measure_unit = "cubes"
    evidence = ("cubes_in_zone", "zone_cubes_hand_touched", "mean_displacement_cm")
    catalogue_entry: ClassVar[dict[str, Any]] = {"texts": ["Nudge one cube into the zone with the broom.",
                                 "Use the broom to push a cube over the line."],
                       "prior": _sweep_prior()}

    def evaluate(self) -> dict[str, Any]:
        info = super().evaluate()
        info["success"] = (info["cubes_in_zone"] >= 1.0) & ~info["fail"]
        return info

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        return torch.clamp(info["cubes_in_zone"], max=1.0)
