"""Typed pipeline configuration, validated before any work starts."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from prl.constants import EPISODE_FRAMES, REPO_ROOT, TASKS


class ConfigError(ValueError):
    """A configuration value is invalid; the message names it."""


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of one pipeline run."""

    profile: str = "quick"
    """Named preset: 'quick' (laptop minutes) or 'paper' (the paper's scale)."""
    tasks: tuple[str, ...] = TASKS
    """Tasks to run, a subset of ``prl.constants.TASKS`` (the paper's four, each simulated in ``envs/tasks``)."""
    seed: int = 0
    """Run seed; every scene seed derives from it."""
    eval_scenes: int = 8
    """Randomised scenes on which the expert and sampled plans are executed."""
    episode_frames: int = EPISODE_FRAMES
    """Physics frames in one plan episode (``EPISODE_SECONDS`` at ``SIM_FREQ``)."""
    output_dir: Path = field(default_factory=lambda: REPO_ROOT / "outputs")
    """Where run outputs (pictures, datasets) are written."""
    render: bool = True
    """Render pictures of each executor stage (needs a Vulkan device)."""
    demos_per_task: int = 4
    """Successful demonstrations kept per task by scene synthesis (paper: 2,000)."""
    n_shards: int = 2
    """Synthesis shards per task (the unit of parallel work; fixed, so results do not depend on workers)."""
    workers: int = 2
    """Dask worker processes of the local cluster."""
    dask_address: str | None = None
    """Address of a running Dask scheduler to use instead of a local cluster."""
    train_rn: bool = True
    """Run the Representation Network stages (PointNet, RN training, RN evaluation in simulation)."""
    pn_epochs: int = 8
    """PointNet pre-training epochs (on synthetic tool/object point clouds)."""
    pn_shapes: int = 1200
    """Synthetic shapes in the PointNet pre-training set."""
    n_points: int = 512
    """Surface points per tool / object cloud."""
    rn_epochs: int = 30
    """RN training epochs (paper: 200)."""
    rn_val_fraction: float = 0.2
    """Share of the scenes (by seed) held out from RN training."""
    rn_eval_scenes: int = 4
    """Fresh scenes on which the RN's plan (and a prior-sampled plan) is executed, per split."""
    wide_randomization: float = 2.0
    """Randomisation half-width scale of the harder evaluation split (1 = the training ranges)."""
    train_ln: bool = True
    """Run the Learning Network stage after the RN stages (it reads their features; off when ``train_rn`` is)."""
    ln_timesteps: int = 64
    """RL timesteps (plan episodes) of each LN run (paper: 3200; one A2C update takes 64)."""
    ln_demo_steps: int | None = None
    """Demonstration transitions the LN is pre-trained on (paper's ablation: 1280; at most demos_per_task;
    None: 1280 or all of a task's demos if it has fewer; 0: pure RL)."""
    ln_envs: int = 2
    """Plan environments stepped in parallel by each LN run (a divisor of 64)."""

    def __post_init__(self) -> None:
        if self.profile not in PROFILES:
            raise ConfigError(f"unknown profile {self.profile!r}; known: {sorted(PROFILES)}")
        if not self.tasks:
            raise ConfigError("tasks is empty; give at least one of " + ", ".join(TASKS))
        for task in self.tasks:
            if task not in TASKS:
                raise ConfigError(f"unknown task {task!r}; known tasks: {', '.join(TASKS)}")
        for name in ("eval_scenes", "episode_frames", "demos_per_task", "n_shards", "workers", "pn_epochs",
                     "pn_shapes", "n_points", "rn_epochs", "rn_eval_scenes", "ln_timesteps", "ln_envs"):
            value = getattr(self, name)
            if not isinstance(value, int) or value <= 0:
                raise ConfigError(f"{name} must be a positive integer, got {value!r}")
        if not isinstance(self.rn_val_fraction, float) or not 0.0 < self.rn_val_fraction < 1.0:
            raise ConfigError(f"rn_val_fraction must be a number in (0, 1), got {self.rn_val_fraction!r}")
        if not isinstance(self.wide_randomization, (int, float)) or not self.wide_randomization >= 1.0:
            raise ConfigError(f"wide_randomization must be a number >= 1, got {self.wide_randomization!r}")
        if self.train_rn and self.demos_per_task * len(self.tasks) < 3:
            raise ConfigError(f"the RN needs at least 3 demos (2 to train on, BatchNorm needs a pair; 1 held out); "
                              f"demos_per_task={self.demos_per_task} with {len(self.tasks)} task(s) "
                              f"(pass more demos, or skip the RN stages)")
        if self.ln_demo_steps is None:
            object.__setattr__(self, "ln_demo_steps", min(PAPER_LN_DEMO_STEPS, self.demos_per_task))
        if isinstance(self.ln_demo_steps, bool) or not isinstance(self.ln_demo_steps, int) or self.ln_demo_steps < 0:
            raise ConfigError(f"ln_demo_steps must be a non-negative integer, got {self.ln_demo_steps!r}")
        if self.train_rn and self.train_ln and self.ln_demo_steps > self.demos_per_task:
            raise ConfigError(f"ln_demo_steps={self.ln_demo_steps} exceeds demos_per_task={self.demos_per_task}: "
                              f"the LN cannot be pre-trained on more demonstrations than synthesis keeps")
        if 64 % self.ln_envs:
            raise ConfigError(f"ln_envs must divide the 64 steps of an A2C update, got {self.ln_envs!r}")
        if not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"seed must be a non-negative integer, got {self.seed!r}")
        out = Path(self.output_dir)
        probe = out if out.exists() else next((p for p in out.parents if p.exists()), Path("/"))
        if not probe.is_dir() or not os.access(probe, os.W_OK):
            raise ConfigError(f"output_dir {str(out)!r} is not writable (checked {str(probe)!r})")
        object.__setattr__(self, "output_dir", out.resolve())


PAPER_LN_DEMO_STEPS = 1280
"""The demonstration steps of the paper's LN (its ablation's reference point)."""

PROFILES: dict[str, dict] = {
    "quick": {"eval_scenes": 8, "demos_per_task": 4, "n_shards": 2, "rn_epochs": 30, "rn_eval_scenes": 4,
              "ln_timesteps": 64},
    "paper": {"eval_scenes": 50, "demos_per_task": 2000, "n_shards": 16, "rn_epochs": 200, "rn_eval_scenes": 50,
              "pn_epochs": 30, "pn_shapes": 4000, "ln_timesteps": 3200},
}


def make_config(profile: str = "quick", **overrides) -> PipelineConfig:
    """The named profile's config with ``overrides`` (None values ignored) applied."""
    if profile not in PROFILES:
        raise ConfigError(f"unknown profile {profile!r}; known: {sorted(PROFILES)}")
    clean = {k: v for k, v in overrides.items() if v is not None}
    return PipelineConfig(profile=profile, **{**PROFILES[profile], **clean})  # one construction: derived defaults follow
