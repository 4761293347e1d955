"""The points of the LN report (``prl.report``): the groups that the summaries fall into (a row of the report: task,
method, K, timesteps) and the planned experiment, the issues' grid of points that the report counts as done or
missing (``planned_points``).

The paper's four tasks: physics K = 1,280 and K = 0, BC, joint control and imitation on 3 seeds, joint control
and joint_bc at equal frames on the first, the hammer's further K. The task variants (``PLANNED_VARIANTS``), where
the best fixed plan succeeds on at most 0.6 of the scenes and methods can separate: the same arms on 3 seeds,
joint_bc at equal frames on all 3, and physics_gated where the paper's reward pays failures
(``GATED_VARIANTS``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from prl.config import LN_METHODS, PAPER_LN_DEMO_STEPS, LNConfig
from prl.constants import TASKS

PAPER_TIMESTEPS = LNConfig().timesteps
"""The paper's RL budget (3,200 timesteps), the experiment's for every point but joint control at equal frames."""
PLAN_SEEDS: tuple[int, ...] = (0, 1, 2)
"""The seeds of every planned point."""
HAMMER_EXTRA_K: tuple[int, ...] = (320, 640, 2560)
"""The hammer's further demonstration steps (the paper's ablation axis, beside 0 and 1,280)."""
JOINT_FRAMES_PER_STEP = 5
"""Physics frames per joint-control step (``envs.joint_env.JOINT_FRAMES_PER_STEP``; a test keeps them equal): the
equal-frames budget is the plan runs' frames over this."""
PLANNED_VARIANTS: tuple[str, ...] = ("hammer_mixed", "sweep_mixed", "tweeze_mixed", "unscrew_mixed")
"""The task variants of the comparison (each holds under the variant search: its best fixed plan <= 0.6)."""
GATED_VARIANTS: tuple[str, ...] = ("tweeze_mixed", "unscrew_mixed")
"""The variants whose physics K = 1,280 points were paid at least as much for failures as for successes (the
report's reward table), so that the comparison also runs the reward paid only on success (``physics_gated``)."""


@dataclass(frozen=True, order=True)
class Group:
    """The points that differ only in their seed: a row of the report."""

    task_index: int
    """Position of the task in ``prl.constants.TASKS`` (unknown tasks after them): the rows' order."""
    task: str
    """Task name."""
    method_index: int
    """Position of the method in ``prl.config.LN_METHODS``."""
    method: str
    """An LN method (``prl.config.LN_METHODS``)."""
    demo_steps: int
    """K."""
    timesteps: int
    """RL timesteps trained."""

    @property
    def at_planned_budget(self) -> bool:
        """Trained for the budget the experiment compares the method at: the paper's RL timesteps; none for
        imitation (no RL); the plan runs' physics frames (more timesteps) for joint_bc."""
        if self.method == "imitation":
            return True
        return self.timesteps > PAPER_TIMESTEPS if self.method == "joint_bc" else self.timesteps == PAPER_TIMESTEPS

    @property
    def label(self) -> str:
        """``physics K=1280``, ``bc K=1280``, ``joint``, ``imitation K=1280 (ACT, joint space)``; the budget appended
        unless it is the paper's."""
        base = "joint control" if self.method == "joint" else f"{self.method} K={self.demo_steps}"
        if self.method == "imitation":
            return f"{base} (ACT, joint space)"
        return base if self.timesteps == PAPER_TIMESTEPS else f"{base}, {self.timesteps:,} steps"


def group_of(summary: Mapping[str, Any]) -> Group:
    """The ``Group`` of one summary."""
    p = summary["point"]
    task_index = TASKS.index(p["task"]) if p["task"] in TASKS else len(TASKS)
    method_index = LN_METHODS.index(p["method"]) if p["method"] in LN_METHODS else len(LN_METHODS)
    return Group(task_index, p["task"], method_index, p["method"], int(p["demo_steps"]), int(summary["timesteps"]))


def grouped(summaries: Mapping[str, Mapping[str, Any]]) -> dict[Group, list[Mapping[str, Any]]]:
    """The summaries by group (sorted), each group's by seed."""
    out: dict[Group, list[Mapping[str, Any]]] = {}
    for s in summaries.values():
        out.setdefault(group_of(s), []).append(s)
    return {g: sorted(out[g], key=lambda s: s["point"]["seed"]) for g in sorted(out)}


@dataclass(frozen=True)
class Planned:
    """One point of the planned experiment (the issue's)."""

    task: str
    """Task name."""
    method: str
    """An LN method (``prl.config.LN_METHODS``)."""
    demo_steps: int
    """K."""
    seed: int
    """Seed."""
    equal_frames: bool = False
    """At the plan runs' physics frames (any budget above the paper's: joint control, joint_bc) rather than 3,200
    steps."""

    def done_by(self, summary: Mapping[str, Any]) -> bool:
        """Whether ``summary`` is this point."""
        p = summary["point"]
        same = (p["task"], p["method"], p["demo_steps"], p["seed"]) == (self.task, self.method, self.demo_steps,
                                                                           self.seed)
        t = int(summary["timesteps"])
        return same and (t > PAPER_TIMESTEPS if self.equal_frames else t == PAPER_TIMESTEPS or p["method"] == "imitation")


def planned_points(tasks: Sequence[str] = TASKS, seeds: Sequence[int] = PLAN_SEEDS,
                   variants: Sequence[str] = PLANNED_VARIANTS) -> list[Planned]:
    """The experiment of the issues: per task physics K = 1,280, BC K = 1,280, physics K = 0 and joint control at
    3,200 timesteps and imitation of the same K = 1,280 demonstrations on ``seeds``, joint control and joint_bc
    (K = 1,280) at the plan runs' frames on the first seed; the hammer also physics K in ``HAMMER_EXTRA_K``. Per
    variant the same arms on ``seeds`` but joint control at equal frames, joint_bc at equal frames on every seed, and
    physics_gated K = 1,280 on the ``GATED_VARIANTS``."""
    out = []
    arms = [("physics", PAPER_LN_DEMO_STEPS), ("bc", PAPER_LN_DEMO_STEPS), ("physics", 0), ("joint", 0),
            ("imitation", PAPER_LN_DEMO_STEPS)]
    for t in tasks:
        extra = [("physics", k) for k in HAMMER_EXTRA_K] if t == "hammer" else []
        out += [Planned(t, v, k, s) for v, k in arms + extra for s in seeds]
        out.append(Planned(t, "joint", 0, seeds[0], equal_frames=True))
        out.append(Planned(t, "joint_bc", PAPER_LN_DEMO_STEPS, seeds[0], equal_frames=True))
    for t in variants:
        gated = [("physics_gated", PAPER_LN_DEMO_STEPS)] if t in GATED_VARIANTS else []
        out += [Planned(t, v, k, s) for v, k in arms + gated for s in seeds]
        out += [Planned(t, "joint_bc", PAPER_LN_DEMO_STEPS, s, equal_frames=True) for s in seeds]
    return out


def missing_points(summaries: Mapping[str, Mapping[str, Any]], plan: Sequence[Planned]) -> list[Planned]:
    """The planned points that no summary is."""
    return [p for p in plan if not any(p.done_by(s) for s in summaries.values())]

def equal_frames_budget(groups: Mapping[Group, Sequence[Mapping[str, Any]]], task: str) -> int | None:
    """Joint-control steps with the physics frames of ``task``'s K = 1,280 plan runs (mean of their final frames
    over ``JOINT_FRAMES_PER_STEP``, rounded up to a whole A2C update of 64); None before those runs exist."""
    frames = [s["rows"][-1]["frames"] for g, m in groups.items() for s in m
              if g.task == task and g.method == "physics" and g.demo_steps == PAPER_LN_DEMO_STEPS
              and g.timesteps == PAPER_TIMESTEPS and s["rows"]]
    if not frames:
        return None
    steps = float(np.mean(frames)) / JOINT_FRAMES_PER_STEP
    return int(np.ceil(steps / 64.0) * 64)
