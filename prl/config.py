"""Typed configuration, validated before any work starts: the pipeline's, the LN's, the LN ablation sweep's.

The CLIs are generated from these dataclasses (``prl.cli``): a flag is its field's name (``--eval-scenes``,
``--ln-timesteps`` for the nested LN settings), and the Prefect flows take the same names as ``overrides``.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, get_origin, get_type_hints

from prl.constants import EPISODE_FRAMES, REPO_ROOT, TASKS
from prl.export_schema import VideoSpec
from prl.imitation import ImitationConfig
from prl.proposal import ProposalConfig
from prl.task_registry import known_tasks


class ConfigError(ValueError):
    """A configuration value is invalid; the message names it."""


def check_task_names(tasks: list[str]) -> None:
    """ConfigError naming the unknown ones of ``tasks`` (a ``--tasks`` list), or an empty list."""
    known = known_tasks()
    unknown = [t for t in tasks if t not in known]
    if unknown or not tasks:
        raise ConfigError(f"unknown task(s) {unknown or tasks} in --tasks; known: {', '.join(known)}")


PAPER_LN_DEMO_STEPS = 1280
"""The demonstration steps of the paper's LN (its ablation's reference point)."""

PRETRAIN_MODES: tuple[str, ...] = ("actor_critic", "bc")
"""Demonstration pre-training: actor and critic (the paper), or the actor alone (behaviour cloning)."""

PAPER_LN_METHODS: tuple[str, ...] = ("physics", "bc", "joint")
"""The paper's LN methods (its Fig 8), a sweep's default: physics-guided A2C with actor+critic pre-training, the
same with BC, joint control."""

LN_METHODS: tuple[str, ...] = (*PAPER_LN_METHODS, "physics_gated", "joint_bc", "imitation")
"""Every LN method: the paper's; ``physics_gated``, the physics method whose A2C reward is the task's measure
only on an episode that meets the task's success rule (0 otherwise; ``flows.train_ln.gated_rewards``). Where the
rule asks more than the measure (the unscrew's grip), the paper's reward can pay most for plans that fail;
``joint_bc``, joint control (A2C on joint targets) whose actor is first cloned from the same K demonstrations'
joint actions and whose critic is fitted to their returns (``prl.joint_bc``, DAPG's protocol); and ``imitation``,
no RL: LeRobot's ACT trained on the same K demonstrations' joint actions (``prl.imitation``) and rolled out in the
joint-control environment."""

JOINT_A2C_METHODS: tuple[str, ...] = ("joint", "joint_bc")
"""The methods whose A2C acts in the joint-control environment (``prl.version.JOINT_METHODS`` but imitation, which
trains no A2C)."""


@dataclass(frozen=True)
class LNConfig:
    """The Learning Network's settings (``prl.ln``). The defaults are the paper's (Sec. V-B) and their one
    definition; everything they leave open is SB3's A2C default (recorded by ``params``)."""

    timesteps: int = 3200
    """RL timesteps (plan episodes) after pre-training (paper: 3200)."""
    learning_rate: float = 7e-4
    """A2C learning rate (RMSprop)."""
    steps_per_update: int = 64
    """Samples per A2C update, n_steps x n_envs (paper: 64); also the pre-training minibatch."""
    gamma: float = 0.99
    """Discount factor."""
    gae_lambda: float = 0.95
    """GAE lambda."""
    ent_coef: float = 0.01
    """Entropy coefficient."""
    hidden: tuple[int, ...] = (256, 256)
    """Hidden layer widths of both the policy and the value net."""
    n_envs: int = 1
    """Plan environments stepped in parallel (subprocesses when > 1); a divisor of steps_per_update."""
    demo_steps: int | None = None
    """Demonstration transitions used by pre-training (0: pure RL; None: the paper's 1280, or all of a
    task's demonstrations if it has fewer)."""
    pretrain_mode: str = "actor_critic"
    """One of ``PRETRAIN_MODES``."""
    pretrain_epochs: int = 10
    """Passes over the demo_steps transitions."""
    seed: int = 0
    """Seed of the A2C and of the demonstrations' shuffle."""
    extra: dict[str, Any] = field(default_factory=dict, hash=False)
    """Further SB3 A2C keyword arguments, as JSON on the command line (empty in the paper's settings)."""

    def __post_init__(self) -> None:
        if isinstance(self.hidden, list):
            object.__setattr__(self, "hidden", tuple(self.hidden))
        ints = {"timesteps": (self.timesteps, 0), "steps_per_update": (self.steps_per_update, 1),
                "n_envs": (self.n_envs, 1), "pretrain_epochs": (self.pretrain_epochs, 1), "seed": (self.seed, 0)}
        if self.demo_steps is not None:
            ints["demo_steps"] = (self.demo_steps, 0)
        for name, (value, low) in ints.items():
            if not _is_int(value) or value < low:
                raise ConfigError(f"ln.{name} must be an integer >= {low}, got {value!r}")
        for name in ("learning_rate", "gamma", "gae_lambda", "ent_coef"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
                raise ConfigError(f"ln.{name} must be a finite number >= 0, got {value!r}")
        if self.steps_per_update % self.n_envs:
            raise ConfigError(f"ln.n_envs must divide ln.steps_per_update ({self.steps_per_update}), the samples of "
                              f"one A2C update (n_steps x n_envs), got {self.n_envs!r}")
        if not self.hidden or any(not _is_int(h) or h < 1 for h in self.hidden):
            raise ConfigError(f"ln.hidden must be positive layer widths, got {self.hidden!r}")
        if self.pretrain_mode not in PRETRAIN_MODES:
            raise ConfigError(f"unknown ln.pretrain_mode {self.pretrain_mode!r}; known: {', '.join(PRETRAIN_MODES)}")
        if not isinstance(self.extra, dict):
            raise ConfigError(f"ln.extra must be a mapping of SB3 A2C keyword arguments, got {self.extra!r}")

    @property
    def n_steps(self) -> int:
        """SB3's ``n_steps``: steps per environment per update."""
        return self.steps_per_update // self.n_envs

    def a2c_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``stable_baselines3.A2C`` (without policy, env and features)."""
        return {"learning_rate": self.learning_rate, "n_steps": self.n_steps, "gamma": self.gamma,
                "gae_lambda": self.gae_lambda, "ent_coef": self.ent_coef, "seed": self.seed, **self.extra}

    def params(self) -> dict[str, Any]:
        """Every setting, for MLflow: this config plus the SB3 defaults it leaves in place."""
        # heavy: torch (stable-baselines3); this module stays pure (the CLIs and config checks import it without
        # torch): only recording an LN run's parameters needs SB3's signature
        from stable_baselines3 import A2C

        defaults = {k: v.default for k, v in inspect.signature(A2C.__init__).parameters.items()
                    if k not in ("self", "policy", "env", "policy_kwargs", "tensorboard_log", "verbose", "device",
                                 "_init_setup_model", "seed", "learning_rate", "n_steps", "gamma", "gae_lambda",
                                 "ent_coef")}
        return {**{f"ln.{k}": v for k, v in dataclasses.asdict(self).items() if k != "extra"},
                **{f"sb3.{k}": self.extra.get(k, v) for k, v in defaults.items()}}


def _check_ln_set_per_point(ln: LNConfig, names: tuple[str, ...], why: str) -> None:
    """ConfigError naming an LN setting that each LN point sets itself, when given another value than the default."""
    for name in names:
        value, default = getattr(ln, name), LNConfig.__dataclass_fields__[name].default
        if value != default:
            raise ConfigError(f"ln.{name} is set per LN point ({why}); leave it at {default!r}, got {value!r}")


def _pipeline_ln() -> LNConfig:
    return LNConfig(timesteps=64, n_envs=2)


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of one pipeline run."""

    LN_SET_PER_POINT: ClassVar[tuple[str, ...]] = ("pretrain_mode", "seed")
    """LN settings the pipeline's LN points take from elsewhere (the physics method; ``seed``): no flags."""

    profile: str = "quick"
    """Named preset: 'quick' (laptop minutes) or 'paper' (the paper's scale)."""
    tasks: tuple[str, ...] = TASKS
    """Tasks to run (default: the paper's four, ``prl.constants.TASKS``): any task of ``envs/tasks`` or declared in
    this process (``prl.task_registry.known_tasks``: the paper's four, their variants ``hammer_mixed``, ...)."""
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
    video: bool = True
    """Write two camera videos per episode into the dataset, rendered by replaying each demo (needs a Vulkan
    device; docs/guide/design.md "Dataset video")."""
    video_width: int = VideoSpec.width
    """Width of the dataset's camera pictures, pixels."""
    video_height: int = VideoSpec.height
    """Height of the dataset's camera pictures, pixels."""
    video_fps: int = VideoSpec.fps
    """Camera pictures per second, a divisor of the dataset's 50 fps; each is held until the next."""
    demos_per_task: int = 4
    """Successful demonstrations kept per task by scene synthesis (paper: 2,000)."""
    n_shards: int = 2
    """Synthesis shards per task (the unit of parallel work; fixed, so results do not depend on workers)."""
    proposal: str = ProposalConfig.kind
    """Where synthesis draws plans from: 'prior' (the task's prior) or 'adaptive' (the cross-entropy method
    between rounds, floored at a fraction of the prior; the kept demos are weighted back to the prior:
    ``prl.proposal``)."""
    round_attempts: int = ProposalConfig.round_attempts
    """Attempts per shard per synthesis round (the adaptive proposal is updated between rounds)."""
    proposal_smoothing: float = ProposalConfig.smoothing
    """Weight of a round's success frequencies in the adaptive proposal's update."""
    proposal_floor: float = ProposalConfig.floor
    """Every choice keeps at least this fraction of its prior probability in the adaptive proposal."""
    proposal_defensive: float = ProposalConfig.defensive
    """Share of the adaptive rounds' plans drawn from the prior (every demo's weight is at most 1 / this)."""
    proposal_replay: float = ProposalConfig.replay
    """Share of the adaptive rounds' other plans that replay an earlier round's successful plan (0: none)."""
    proposal_weighted: bool = ProposalConfig.weighted
    """Count each success by its importance weight in the adaptive proposal's update and replays (towards the
    prior's successful plans rather than the most frequent ones: ``prl.proposal``)."""
    replay_check: bool = False
    """Keep a demo only when its ``action`` stream, replayed open loop at the dataset's 50 Hz in the joint-control
    environment, succeeds again (``envs.replay.demo_replays``; one more episode per kept demo): a dataset every
    episode of which ``prl-replay`` reproduces, for joint-space learners (docs/guide/design.md "Joint space")."""
    workers: int = 2
    """Dask worker processes of the local cluster; also the processes that write the dataset (without video, from
    ``prl.export_merge.PARALLEL_MIN_EPISODES`` episodes per process)."""
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
    rn_weighted: bool = True
    """Weight each demo in the RN's loss by prior / proposal (``prl.proposal``), so that the RN learns the plans
    that succeed under the task's prior; False: the demos as the synthesis drew them (under the adaptive proposal,
    concentrated on the plans it converged on)."""
    rn_val_fraction: float = 0.2
    """Share of the scenes (by seed) held out from RN training."""
    rn_eval_scenes: int = 4
    """Fresh scenes on which the RN's plan (and a prior-sampled plan) is executed, per split."""
    wide_randomization: float = 2.0
    """Randomisation half-width scale of the harder evaluation split (1 = the training ranges)."""
    train_ln: bool = True
    """Run the Learning Network stage after the RN stages (it reads their features; off when ``train_rn`` is)."""
    ln: LNConfig = field(default_factory=_pipeline_ln)
    """The LN runs' settings (one per task; the paper's but timesteps, by profile, and 2 parallel envs);
    demo_steps None: 1280 or all of a task's demos if it has fewer (at most demos_per_task)."""

    def __post_init__(self) -> None:
        if self.profile not in PROFILES:
            raise ConfigError(f"unknown profile {self.profile!r}; known: {sorted(PROFILES)}")
        if not self.tasks:
            raise ConfigError("tasks is empty; give at least one of " + ", ".join(TASKS))
        known = known_tasks()
        for task in self.tasks:
            if task not in known:
                raise ConfigError(f"unknown task {task!r}; known tasks: {', '.join(known)}")
        for name in ("eval_scenes", "episode_frames", "demos_per_task", "n_shards", "workers", "pn_epochs",
                     "pn_shapes", "n_points", "rn_epochs", "rn_eval_scenes"):
            value = getattr(self, name)
            if not _is_int(value) or value <= 0:
                raise ConfigError(f"{name} must be a positive integer, got {value!r}")
        if not isinstance(self.rn_val_fraction, float) or not 0.0 < self.rn_val_fraction < 1.0:
            raise ConfigError(f"rn_val_fraction must be a number in (0, 1), got {self.rn_val_fraction!r}")
        if not isinstance(self.wide_randomization, (int, float)) or not self.wide_randomization >= 1.0:
            raise ConfigError(f"wide_randomization must be a number >= 1, got {self.wide_randomization!r}")
        if self.train_rn and self.demos_per_task * len(self.tasks) < 3:
            raise ConfigError(f"the RN needs at least 3 demos (2 to train on, BatchNorm needs a pair; 1 held out); "
                              f"demos_per_task={self.demos_per_task} with {len(self.tasks)} task(s) "
                              f"(pass more demos, or skip the RN stages)")
        if not isinstance(self.ln, LNConfig):
            raise ConfigError(f"ln must be an LNConfig, got {self.ln!r}")
        if self.ln.timesteps <= 0:
            raise ConfigError(f"ln.timesteps must be a positive integer, got {self.ln.timesteps!r}")
        _check_ln_set_per_point(self.ln, self.LN_SET_PER_POINT, "the pipeline's are physics-guided and seeded by seed")
        if self.ln.demo_steps is None:
            object.__setattr__(self, "ln", dataclasses.replace(
                self.ln, demo_steps=min(PAPER_LN_DEMO_STEPS, self.demos_per_task)))
        if self.train_rn and self.train_ln and self.ln.demo_steps > self.demos_per_task:
            raise ConfigError(f"ln.demo_steps={self.ln.demo_steps} exceeds demos_per_task={self.demos_per_task}: "
                              f"the LN cannot be pre-trained on more demonstrations than synthesis keeps")
        if not _is_int(self.seed) or self.seed < 0:
            raise ConfigError(f"seed must be a non-negative integer, got {self.seed!r}")
        try:
            self.proposal_config()
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        for name in ("video", "rn_weighted"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"{name} must be true or false, got {getattr(self, name)!r}")
        try:
            self.video_spec()
        except ValueError as exc:
            raise ConfigError(str(exc).replace("video ", "video_", 1)) from None
        out = Path(self.output_dir)
        probe = out if out.exists() else next((p for p in out.parents if p.exists()), Path("/"))
        if not probe.is_dir() or not os.access(probe, os.W_OK):
            raise ConfigError(f"output_dir {str(out)!r} is not writable (checked {str(probe)!r})")
        object.__setattr__(self, "output_dir", out.resolve())

    def proposal_config(self) -> ProposalConfig:
        """Synthesis's proposal settings (``prl.proposal``)."""
        return ProposalConfig(kind=self.proposal, round_attempts=self.round_attempts,
                              smoothing=self.proposal_smoothing, floor=self.proposal_floor,
                              defensive=self.proposal_defensive, replay=self.proposal_replay,
                              weighted=self.proposal_weighted)

    def video_spec(self) -> VideoSpec:
        """The dataset video's settings (also when ``video`` is off: they are checked either way)."""
        return VideoSpec(width=self.video_width, height=self.video_height, fps=self.video_fps)


PROFILES: dict[str, dict] = {
    "quick": {"eval_scenes": 8, "demos_per_task": 4, "n_shards": 2, "rn_epochs": 30, "rn_eval_scenes": 4,
              "ln": {"timesteps": 64}},
    "paper": {"eval_scenes": 50, "demos_per_task": 2000, "n_shards": 16, "rn_epochs": 200, "rn_eval_scenes": 50,
              "pn_epochs": 30, "pn_shapes": 4000, "ln": {"timesteps": LNConfig.timesteps}, "video": False},
}
"""Each profile's settings over ``PipelineConfig``'s defaults; ``ln`` is merged over the default LN settings. The
paper profile leaves the dataset video out (``--video`` puts it in): it would add about 2 h to the export of its
8,000 demos on a 2-core machine (docs/archive/speed.md "Dataset export")."""


@dataclass(frozen=True)
class AblationConfig:
    """Settings of one LN ablation sweep (paper Fig 8, ``flows.ablation``): its points are tasks x methods x
    demo_steps x seeds, each an LN run with the ``ln`` settings."""

    LN_SET_PER_POINT: ClassVar[tuple[str, ...]] = ("demo_steps", "pretrain_mode", "seed")
    """LN settings each sweep point sets itself (demo_steps, method, seeds): no flags."""
    IMITATION_SET_PER_POINT: ClassVar[tuple[str, ...]] = ("seed",)
    """Imitation settings each sweep point sets itself (its seed): no flags."""

    dataset_root: Path | None = None
    """Exported LeRobot dataset root (the pipeline's datasets/...); needed by the plan-space methods (physics, bc), not
    by a sweep of joint control alone (no demonstrations, no x)."""
    pointnet_path: Path | None = None
    """The PointNet checkpoint the RN used (models/pointnet-*.pt); needed as ``dataset_root`` is."""
    repo_id: str | None = None
    """The dataset's repo id (None: from its meta/info.json, else prl/<directory name>)."""
    tasks: tuple[str, ...] = ("hammer",)
    """Tasks swept, each with demonstrations in the dataset (``prl.task_registry.known_tasks``)."""
    methods: tuple[str, ...] = PAPER_LN_METHODS
    """LN methods swept (``LN_METHODS``): physics (actor+critic pre-training), bc, joint (joint control, no
    demonstrations); physics_gated, joint_bc and imitation only when named."""
    demo_steps: tuple[int, ...] = (0, PAPER_LN_DEMO_STEPS)
    """Demonstration steps K swept (paper: 0, 320, 640, 1280, 2560); bc, joint_bc and imitation only for K > 0, joint once."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Seeds of each point."""
    eval_scenes: int = 50
    """Unseen scenes each final policy is evaluated on."""
    eval_seed: int = 0
    """Run seed the evaluation scenes derive from (the pipeline's rn-eval scenes of that seed)."""
    workers: int = 2
    """Dask worker processes of the local cluster (points run one per worker)."""
    dask_address: str | None = None
    """Address of a running Dask scheduler to use instead of a local cluster."""
    output_dir: Path = Path("outputs/ablation")
    """Where demonstrations, checkpoints, point summaries and Fig 8 are written."""
    results_dir: Path | None = None
    """Where each finished point also writes its committed summary, <point>-t<timesteps>.json (the experiment:
    docs/results/ln); a point whose summary there holds today's settings, code version and dataset is not run
    again (flows/ln_results.py). None: only output_dir's summaries and the MLflow sweep parent resume."""
    n_points: int = 512
    """Surface points per tool / object cloud (the PointNet's)."""
    reevaluate: bool = False
    """Evaluate the finished points' final policies again (after a task's success criterion changed)."""
    ln: LNConfig = field(default_factory=LNConfig)
    """Every point's LN settings (the paper's; one plan env per point)."""
    imitation: ImitationConfig = field(default_factory=ImitationConfig)
    """The imitation points' policy and training (``prl.imitation``; each point sets its seed)."""

    def __post_init__(self) -> None:
        if not isinstance(self.imitation, ImitationConfig):
            raise ConfigError(f"imitation must be an ImitationConfig, got {self.imitation!r}")
        for name, known in (("tasks", known_tasks()), ("methods", LN_METHODS)):
            values = getattr(self, name)
            if not values:
                raise ConfigError(f"{name} is empty; give at least one of {', '.join(known)}")
            for v in values:
                if v not in known:
                    raise ConfigError(f"unknown {name[:-1]} {v!r} in {name}; known: {', '.join(known)}")
        for name in ("demo_steps", "seeds"):
            values = getattr(self, name)
            if not values or any(not _is_int(v) or v < 0 for v in values):
                raise ConfigError(f"{name} must be non-negative integers (at least one), got {values!r}")
        for name, low in (("eval_scenes", 1), ("eval_seed", 0), ("workers", 1), ("n_points", 1)):
            value = getattr(self, name)
            if not _is_int(value) or value < low:
                raise ConfigError(f"{name} must be an integer >= {low}, got {value!r}")
        if not isinstance(self.reevaluate, bool):
            raise ConfigError(f"reevaluate must be true or false, got {self.reevaluate!r}")
        if self.results_dir is not None:
            if not isinstance(self.results_dir, (str, Path)) or not str(self.results_dir):
                raise ConfigError(f"results_dir must be a path or None, got {self.results_dir!r}")
            object.__setattr__(self, "results_dir", Path(self.results_dir))
            if self.reevaluate:
                raise ConfigError(f"reevaluate cannot write to results_dir {str(self.results_dir)!r}: a policy trained "
                                  f"under one code version and judged under another is a result of neither; "
                                  f"re-evaluate without results_dir, or re-run the points")
        if not isinstance(self.ln, LNConfig):
            raise ConfigError(f"ln must be an LNConfig, got {self.ln!r}")
        _check_ln_set_per_point(self.ln, self.LN_SET_PER_POINT, "by demo_steps, methods and seeds")
        plan_methods = [m for m in self.methods if m != "joint"]
        for name in ("dataset_root", "pointnet_path"):
            value = getattr(self, name)
            if value is None:
                if plan_methods:
                    raise ConfigError(f"{name} is needed by the methods {', '.join(plan_methods)} (demonstrations "
                                      f"and x); only a sweep of joint control alone runs without one")
                continue
            if not isinstance(value, (str, Path)) or not str(value):
                raise ConfigError(f"{name} must be a path, got {value!r}")
            object.__setattr__(self, name, Path(value))
        object.__setattr__(self, "output_dir", Path(self.output_dir))


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def build_config(cls: type, base: dict[str, Any] | None = None, overrides: dict[str, Any] | None = None,
                 prefix: str = "") -> Any:
    """``cls`` from ``base`` with ``overrides`` over it (None values ignored in both): JSON-like values become the
    field's type (lists tuples, strings paths), and a nested dataclass field (``ln``) given as a dict is merged
    over the value so far (or the field's default). ``ConfigError`` naming an unknown or missing setting."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = get_type_hints(cls)
    values: dict[str, Any] = {}
    for layer in (base or {}, overrides or {}):
        for name, value in layer.items():
            if value is None:
                continue
            if name not in fields:
                raise ConfigError(f"unknown setting {prefix + name!r}; known: {', '.join(prefix + f for f in fields)}")
            hint = hints[name]
            if dataclasses.is_dataclass(hint) and isinstance(value, dict):
                current = values.get(name)
                if current is None:
                    f = fields[name]
                    current = f.default_factory() if f.default_factory is not dataclasses.MISSING else hint()
                value = build_config(hint, dataclasses.asdict(current), value, prefix=f"{prefix}{name}.")
            elif isinstance(value, list) and get_origin(hint) is tuple:
                value = tuple(value)
            elif hint is Path and isinstance(value, str):
                value = Path(value)
            values[name] = value
    missing = [n for n, f in fields.items() if n not in values and f.default is dataclasses.MISSING
               and f.default_factory is dataclasses.MISSING]
    if missing:
        raise ConfigError(f"missing setting(s) {', '.join(prefix + n for n in missing)} of {cls.__name__}")
    return cls(**values)


def make_config(profile: str = "quick", **overrides: Any) -> PipelineConfig:
    """The named profile's config with ``overrides`` (None values ignored) applied; ``ln`` may be a dict of LN
    settings merged over the profile's (``ln={"timesteps": 64}``) or an ``LNConfig`` replacing them."""
    if profile not in PROFILES:
        raise ConfigError(f"unknown profile {profile!r}; known: {sorted(PROFILES)}")
    if overrides.get("profile") not in (None, profile):
        raise ConfigError(f"profile is make_config's first argument, not an override (got {overrides['profile']!r})")
    return build_config(PipelineConfig, {"profile": profile, **PROFILES[profile]}, overrides)


def make_ablation_config(dataset_root: str | Path | None = None, pointnet_path: str | Path | None = None,
                         **overrides: Any) -> AblationConfig:
    """The sweep's config: its dataset and PointNet (None for a sweep of joint control alone), ``overrides`` (None
    values ignored) over the defaults; ``ln`` as in ``make_config``."""
    return build_config(AblationConfig, {"dataset_root": dataset_root, "pointnet_path": pointnet_path}, overrides)
