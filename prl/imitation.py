"""Imitation in joint space with LeRobot's own policies: ACT trained on an exported dataset, offline, on a CPU.

The policy reads what the joint-control environment observes (``envs.joint_env``): ``observation.state`` (qpos |
qvel) and ``observation.environment_state`` (``prl.env_state``), and predicts chunks of ``action`` (joint targets at
the dataset's 50 fps, ``prl.export_schema.replay_actions``). Training is lerobot's: its ``LeRobotDataset`` with the
action chunk's delta timestamps, its ``ACTPolicy`` and pre/post-processors (normalisation from the dataset's
stats), its optimizer preset, ``policy.forward`` as the loss; the result is saved with lerobot's
``save_pretrained`` (``config.json``, ``model.safetensors`` and the processors' JSON and safetensors: nothing
executes code on load). ``ImitationActor`` loads it and acts with ``select_action`` (a chunk, then one action a
step), as lerobot's rollout does. The same training runs from lerobot's own command line (``docs/guide/design.md``
"Imitation in joint space").
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prl.export_schema import DEFAULT_REPO_ID, read_scenes, require_feature

IMITATION_INPUTS: tuple[str, ...] = ("observation.state", "observation.environment_state")
"""The dataset features the policy reads: what the joint-control environment observes."""
POLICY_TYPES: tuple[str, ...] = ("act",)
"""LeRobot policies this module trains (state-only ACT; Diffusion Policy's U-Net costs more per sample here)."""


@dataclass(frozen=True)
class ImitationConfig:
    """A LeRobot policy trained on a dataset's demonstrations (ACT, small enough for two CPU cores)."""

    policy: str = "act"
    """LeRobot policy type (``POLICY_TYPES``)."""
    steps: int = 2000
    """Gradient steps."""
    batch_size: int = 32
    """Samples per gradient step."""
    learning_rate: float = 1e-4
    """AdamW learning rate (ACT's preset: weight decay 1e-4, gradient norm clipped at 10)."""
    dim_model: int = 256
    """Transformer width."""
    dim_feedforward: int = 1024
    """Transformer feed-forward width."""
    n_heads: int = 8
    """Attention heads."""
    n_encoder_layers: int = 2
    """Transformer encoder layers."""
    n_decoder_layers: int = 1
    """Transformer decoder layers."""
    chunk_size: int = 25
    """Actions predicted per chunk (0.5 s at 50 fps)."""
    n_action_steps: int = 25
    """Actions of a chunk executed before the policy is asked again."""
    use_vae: bool = True
    """ACT's variational objective (its default)."""
    seed: int = 0
    """Seed of the initial weights and the batch order."""
    log_every: int = 10
    """Steps between two recorded losses."""

    def __post_init__(self) -> None:
        if self.policy not in POLICY_TYPES:
            raise ValueError(f"policy must be one of {POLICY_TYPES}, got {self.policy!r}")
        for name in ("steps", "batch_size", "dim_model", "dim_feedforward", "n_heads", "n_encoder_layers",
                     "n_decoder_layers", "chunk_size", "n_action_steps", "log_every"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if self.n_action_steps > self.chunk_size:
            raise ValueError(f"n_action_steps ({self.n_action_steps}) must not exceed chunk_size ({self.chunk_size})")
        if self.dim_model % self.n_heads:
            raise ValueError(f"dim_model ({self.dim_model}) must be a multiple of n_heads ({self.n_heads})")
        if not self.learning_rate > 0:
            raise ValueError(f"learning_rate must be > 0, got {self.learning_rate!r}")


@dataclass
class ImitationResult:
    """A trained policy: where it is saved, its loss curve and what it was trained on."""

    policy_dir: Path
    """lerobot's ``save_pretrained`` directory (config, weights, processors)."""
    episodes: list[int]
    """Dataset episodes trained on."""
    frames: int
    """Dataset frames of those episodes."""
    losses: list[dict[str, float]] = field(default_factory=list)
    """One row per ``log_every`` steps: ``step``, ``loss`` and ACT's terms (``l1_loss``, ``kld_loss``)."""
    seconds: float = 0.0
    """Training wall time."""


def task_episodes(dataset_root: Path | str, task: str | None = None, limit: int | None = None) -> list[int]:
    """The dataset's episode indices of ``task`` (every episode when None), the first ``limit`` of them.
    ValueError naming a task the dataset does not hold."""
    scenes = read_scenes(dataset_root)
    chosen = [int(s["episode_index"]) for s in scenes if task is None or s["task"] == task]
    if not chosen:
        held = sorted({s["task"] for s in scenes})
        raise ValueError(f"the dataset at {str(dataset_root)!r} holds no {task!r} episode (it holds {held})")
    return chosen[:limit] if limit is not None else chosen


def drawn_episodes(dataset_root: Path | str, task: str, k: int, seed: int) -> list[int]:
    """The dataset episodes of the ``k`` demonstrations a plan-space LN point of ``seed`` is pre-trained on: the
    first ``k`` of the same seeded shuffle of the task's episodes as ``prl.ln.Demonstrations.take`` (whose
    transitions are the task's episodes in the dataset's order, ``prl.ln.task_demonstrations``), so that imitation
    and the plan-space methods learn from the same demonstrations. ValueError naming ``k`` when there are fewer."""
    episodes = task_episodes(dataset_root, task)
    if isinstance(k, bool) or not isinstance(k, int) or not 0 < k <= len(episodes):
        raise ValueError(f"demo_steps={k!r} must be between 1 and the {len(episodes)} {task} episodes of the dataset "
                         f"at {str(dataset_root)!r}")
    return [episodes[i] for i in np.random.default_rng(seed).permutation(len(episodes))[:k]]


def policy_config(cfg: ImitationConfig, features: dict[str, dict[str, Any]]) -> Any:
    """lerobot's ``ACTConfig`` of ``cfg`` on the dataset's ``features`` (``meta/info.json``), reading
    ``IMITATION_INPUTS`` and writing ``action``, on the CPU. ValueError naming a missing feature."""
    from lerobot.configs.types import FeatureType, PolicyFeature  # heavy: lerobot
    from lerobot.policies.act.configuration_act import ACTConfig

    kinds = {"observation.state": FeatureType.STATE, "observation.environment_state": FeatureType.ENV}
    inputs = {}
    for name in IMITATION_INPUTS:
        require_feature(features, name, "the dataset")
        inputs[name] = PolicyFeature(type=kinds[name], shape=tuple(features[name]["shape"]))
    return ACTConfig(
        input_features=inputs, output_features={"action": PolicyFeature(FeatureType.ACTION,
                                                                         tuple(features["action"]["shape"]))},
        device="cpu", push_to_hub=False, pretrained_backbone_weights=None, chunk_size=cfg.chunk_size,
        n_action_steps=cfg.n_action_steps, dim_model=cfg.dim_model, dim_feedforward=cfg.dim_feedforward,
        n_heads=cfg.n_heads, n_encoder_layers=cfg.n_encoder_layers, n_decoder_layers=cfg.n_decoder_layers,
        use_vae=cfg.use_vae, optimizer_lr=cfg.learning_rate, optimizer_lr_backbone=cfg.learning_rate)


def train_imitation(dataset_root: Path | str, cfg: ImitationConfig, out_dir: Path | str,
                    episodes: Sequence[int] | None = None, progress: bool = True,
                    on_log: Callable[[dict[str, float]], None] | None = None) -> ImitationResult:
    """Train ``cfg``'s policy on ``episodes`` (default: all) of the dataset at ``dataset_root`` and save it under
    ``out_dir``; ``on_log(row)`` is called with each loss row. ExportError naming a dataset that is not one,
    ValueError naming a missing feature."""
    import torch  # heavy: torch, lerobot
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors
    from tqdm.auto import tqdm

    from prl.export_check import load_local

    root = Path(dataset_root)
    meta = load_local(root).meta
    config = policy_config(cfg, meta.features)
    chosen = list(episodes) if episodes is not None else list(range(meta.total_episodes))
    torch.manual_seed(cfg.seed)
    ds = LeRobotDataset(DEFAULT_REPO_ID, root=root, episodes=chosen,
                        delta_timestamps=resolve_delta_timestamps(config, meta))
    policy = ACTPolicy(config)
    preprocessor, postprocessor = make_pre_post_processors(config, dataset_stats=meta.stats)
    optimizer = config.get_optimizer_preset().build(policy.get_optim_params())
    loader = torch.utils.data.DataLoader(ds, batch_size=cfg.batch_size, shuffle=True, num_workers=0, drop_last=False,
                                         generator=torch.Generator().manual_seed(cfg.seed))
    result = ImitationResult(policy_dir=Path(out_dir) / "policy", episodes=chosen, frames=len(ds))
    t0, step, batches = time.perf_counter(), 0, iter(loader)
    policy.train()
    with tqdm(total=cfg.steps, desc=f"{cfg.policy} training", unit="step", disable=not progress) as bar:
        while step < cfg.steps:
            try:
                batch = next(batches)
            except StopIteration:
                batches = iter(loader)
                batch = next(batches)
            loss, parts = policy.forward(preprocessor(batch))
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), config.get_optimizer_preset().grad_clip_norm)
            optimizer.step()
            step += 1
            bar.update(1)
            if step % cfg.log_every == 0 or step == cfg.steps:
                row = {"step": float(step), "loss": float(loss.item()),
                       **{k: float(v) for k, v in (parts or {}).items() if np.isscalar(v)}}
                result.losses.append(row)
                bar.set_postfix(loss=f"{row['loss']:.3f}")
                if on_log is not None:
                    on_log(row)
    result.seconds = time.perf_counter() - t0
    policy.eval()
    policy.save_pretrained(result.policy_dir)
    preprocessor.save_pretrained(result.policy_dir)
    postprocessor.save_pretrained(result.policy_dir)
    return result


class ImitationActor:
    """A saved policy (``train_imitation``'s ``policy_dir``) acting on joint-control observations: ``reset()`` at an
    episode's start, then ``actor(state, environment_state)`` -> the joint targets (30,) of the next step."""

    def __init__(self, policy_dir: Path | str) -> None:
        from lerobot.policies.act.modeling_act import ACTPolicy  # heavy: torch, lerobot
        from lerobot.policies.factory import make_pre_post_processors

        policy_dir = Path(policy_dir)
        if not (policy_dir / "model.safetensors").is_file():
            raise FileNotFoundError(f"no trained policy at {str(policy_dir)!r} (model.safetensors is missing)")
        self.policy = ACTPolicy.from_pretrained(policy_dir)
        self.policy.eval()
        self.preprocessor, self.postprocessor = make_pre_post_processors(self.policy.config,
                                                                         pretrained_path=str(policy_dir))

    def reset(self) -> None:
        """Forget the action chunk in progress (a new episode)."""
        self.policy.reset()

    def __call__(self, state: np.ndarray, environment_state: np.ndarray) -> np.ndarray:
        import torch  # heavy: torch (loaded with the policy)

        batch = {"observation.state": torch.as_tensor(np.asarray(state, np.float32))[None],
                 "observation.environment_state": torch.as_tensor(np.asarray(environment_state, np.float32))[None]}
        with torch.no_grad():
            action = self.postprocessor(self.policy.select_action(self.preprocessor(batch)))
        return np.asarray(action, dtype=np.float64).reshape(-1)
