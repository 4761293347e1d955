"""The Learning Network (paper Sec. IV-B, V-B): A2C over the Representation Space, pre-trained on demonstrations.

The LN is stable-baselines3's A2C acting on x, the RN's input (``prl.features``), with the plan
vector as a MultiDiscrete action; one RL step executes one whole plan (``envs.plan_env.PlanEnv``).
The paper's settings are the defaults of ``LNConfig`` (``prl.config``, their one definition): policy and
value nets of two hidden layers of 256, lr 0.0007, 64 steps per update (``n_steps`` x ``n_envs``), gamma
0.99, GAE lambda 0.95, entropy coefficient 0.01, 3200 timesteps; everything else is SB3's default (RMSprop, value coefficient 0.5,
gradient clip 0.5), recorded by ``LNConfig.params``. With one-step episodes (``terminated=True``) the
GAE advantage is r - V(x): the critic is a learned baseline of the plan's reward on this scene.

Pre-training with demonstrations (``pretrain``), our reading of the paper's open points:

- one **demonstration step** is one demonstration transition (x, plan, r): a synthesised episode's
  RN input x, its commanded plan, and its measured reward (the task's measure in its outcome),
  counted like one RL timestep. ``demo_steps = K`` uses K transitions of the exported dataset (the
  first K of a seeded shuffle); asking for more than the dataset holds is an error, not a silent
  re-use. The K transitions are passed over ``pretrain_epochs`` times in minibatches of one A2C
  update's samples (``steps_per_update``, the paper's 64).
- targets are the **commanded plans**, which physics confirmed (every exported demo succeeded), not
  the RN's classifications: the RN is trained on the same plans, so its argmax would feed the LN the
  RN's errors as well. The recovered physical-law labels are not targets (some dimensions have no
  label).
- ``mode="actor_critic"`` (the paper's pre-training): -log pi(plan | x) plus ``vf_coef`` x the squared
  error of V(x) against r; ``mode="bc"`` (behaviour cloning): the actor term alone, the value net
  stays as initialised. Both use the A2C's own optimiser and gradient clip.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from prl.config import PRETRAIN_MODES, LNConfig  # the settings live in the pure config module


class StandardizedX(BaseFeaturesExtractor):
    """(x - mean) / std with fixed statistics (the demonstrations'), stored in the policy and saved with it."""

    def __init__(self, observation_space: Any, mean: Sequence[float], std: Sequence[float]) -> None:
        super().__init__(observation_space, features_dim=int(np.prod(observation_space.shape)))
        self.register_buffer("mean", torch.as_tensor(np.asarray(mean, np.float32)))
        self.register_buffer("std", torch.as_tensor(np.maximum(np.asarray(std, np.float32), 1e-6)))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return (obs.float() - self.mean) / self.std


def make_ln(env: Any, cfg: LNConfig, x_mean: np.ndarray | None = None, x_std: np.ndarray | None = None) -> Any:
    """A fresh A2C with the config's settings on ``env`` (a gymnasium env or SB3 VecEnv). Given ``x_mean`` and
    ``x_std`` (the demonstrations' feature statistics, ``prl.rn.feature_stats``) the policy standardises x with
    them (``StandardizedX``); without, it sees the observation as it is (the joint-control baseline)."""
    from stable_baselines3 import A2C  # heavy: torch (stable-baselines3)

    policy_kwargs: dict[str, Any] = {"net_arch": {"pi": list(cfg.hidden), "vf": list(cfg.hidden)}}
    if x_mean is not None and x_std is not None:
        policy_kwargs |= {"features_extractor_class": StandardizedX,
                          "features_extractor_kwargs": {"mean": np.asarray(x_mean, np.float32).tolist(),
                                                        "std": np.asarray(x_std, np.float32).tolist()}}
    return A2C("MlpPolicy", env, policy_kwargs=policy_kwargs, verbose=0, device="cpu", **cfg.a2c_kwargs())


class PlanActor(torch.nn.Module):
    """The deterministic plan of an LN policy as a plain module of the policy's own layers: features -> actor MLP
    -> action logits -> per-dimension argmax of the probabilities, what SB3's ``policy.predict(x,
    deterministic=True)`` computes for a MultiDiscrete plan. It is what gets exported (``torch.export`` traces
    ``forward``, which SB3's sampling distributions would not let it) and registered as ``prl-ln``."""

    def __init__(self, policy: Any) -> None:
        super().__init__()
        nvec = getattr(policy.action_space, "nvec", None)
        if nvec is None:
            raise ValueError(f"PlanActor needs a MultiDiscrete plan policy, got action space {policy.action_space}")
        self.features = policy.pi_features_extractor
        self.actor = policy.mlp_extractor.policy_net
        self.action_net = policy.action_net
        self.dims = [int(m) for m in nvec]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, n_dims) int64 plan indices of x (B, x_dim)."""
        logits = self.action_net(self.actor(self.features(x.float())))
        # as SB3's Categorical(logits=...).probs: normalised logits, softmax, then the argmax (ties alike)
        return torch.stack([torch.softmax(part - part.logsumexp(-1, keepdim=True), -1).argmax(-1)
                            for part in torch.split(logits, self.dims, dim=1)], dim=1)


@dataclass(frozen=True)
class Demonstrations:
    """Demonstration transitions for pre-training: one per exported episode."""

    x: np.ndarray
    """(N, D) float32 RN inputs."""
    plan: np.ndarray
    """(N, 6) int64 commanded plans (one column per dimension of the action space)."""
    reward: np.ndarray
    """(N,) float32 measured rewards (the task's measure in the episode's outcome)."""
    weight: np.ndarray | None = None
    """(N,) importance weights prior / proposal of the plans (``prl.proposal``): pre-training weights each
    transition's losses by them, so the policy imitates the prior's successful plans, not the proposal's; None: 1."""

    def __post_init__(self) -> None:
        n = len(self.x)
        if self.x.ndim != 2 or self.plan.ndim != 2 or len(self.plan) != n or self.reward.shape != (n,):
            raise ValueError(f"demonstrations must be x (N, D), plan (N, A), reward (N,); got {self.x.shape}, "
                             f"{self.plan.shape}, {self.reward.shape}")
        if self.weight is None:
            object.__setattr__(self, "weight", np.ones(n, np.float32))
        w = np.asarray(self.weight, np.float32)
        if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError(f"demonstration weights must be (N,) = ({n},) finite values >= 0, got shape {w.shape}")
        object.__setattr__(self, "weight", w)

    def take(self, k: int, seed: int) -> Demonstrations:
        """The first ``k`` transitions of a seeded shuffle; ``ValueError`` naming ``k`` when there are fewer."""
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 0:
            raise ValueError(f"demo_steps must be an integer >= 0, got {k!r}")
        if k > len(self.x):
            raise ValueError(f"demo_steps={k} exceeds the {len(self.x)} demonstration transitions available "
                             f"(one per exported episode); synthesise more demos or ask for fewer steps")
        idx = np.random.default_rng(seed).permutation(len(self.x))[:k]
        return Demonstrations(self.x[idx], self.plan[idx], self.reward[idx], self.weight[idx])


def task_demonstrations(task: str, measure_key: str, x: np.ndarray, plans: np.ndarray, tasks: Sequence[str],
                        outcomes: Sequence[dict[str, Any]], weights: np.ndarray | None = None) -> Demonstrations:
    """The demonstration transitions of ``task`` among a dataset's episodes (x from ``prl.features``, plans,
    per-episode task names and outcomes, and the episodes' importance ``weights``, ``prl.features.demo_weights``);
    the reward is the outcome's ``measure_key``. Clear errors when the dataset has no episode of ``task`` or an
    outcome lacks the measure."""
    idx = [i for i, t in enumerate(tasks) if t == task]
    if not idx:
        raise ValueError(f"the dataset has no demonstration of task {task!r} (it has {sorted(set(tasks))})")
    missing = [i for i in idx if measure_key not in outcomes[i]]
    if missing:
        raise ValueError(f"episode {missing[0]} of task {task!r} records no {measure_key!r} in its outcome; "
                         f"the LN's reward needs it (re-export the dataset)")
    reward = np.array([float(outcomes[i][measure_key]) for i in idx], np.float32)
    w = None if weights is None else np.asarray(weights, np.float32)[idx]
    return Demonstrations(np.asarray(x, np.float32)[idx], np.asarray(plans, np.int64)[idx], reward, w)


def pretrain(model: Any, demos: Demonstrations, mode: str = "actor_critic", epochs: int = 10,
             batch_size: int | None = None, seed: int = 0,
             on_batch: Callable[[int, dict[str, float]], None] | None = None) -> list[dict[str, float]]:
    """Pre-train ``model`` (an A2C of ``make_ln``) on ``demos`` (see the module docstring) in minibatches of
    ``batch_size`` (None: one A2C update's samples, ``n_steps x n_envs``); one row of losses per minibatch
    (``actor_loss``, ``critic_loss``, ``expert_prob``: the mean probability of the demonstrated plan). Both losses
    are means weighted by the transitions' ``weight`` (all 1 for demos drawn from the prior)."""
    import torch.nn.functional as F  # heavy: torch

    if mode not in PRETRAIN_MODES:
        raise ValueError(f"unknown pretrain mode {mode!r}; known: {', '.join(PRETRAIN_MODES)}")
    if len(demos.x) == 0:
        return []
    dim = model.observation_space.shape[0]
    if demos.x.shape[1] != dim:
        raise ValueError(f"demonstration x has {demos.x.shape[1]} values, the LN observes {dim}")
    if demos.plan.shape[1] != len(model.action_space.nvec):
        raise ValueError(f"demonstrated plans have {demos.plan.shape[1]} dimensions, the LN acts on "
                         f"{len(model.action_space.nvec)}")
    batch_size = int(batch_size or model.n_steps * model.n_envs)
    policy = model.policy
    policy.set_training_mode(True)
    rng = np.random.default_rng(seed)
    obs = torch.as_tensor(demos.x, dtype=torch.float32)
    act = torch.as_tensor(demos.plan, dtype=torch.int64)
    rew = torch.as_tensor(demos.reward, dtype=torch.float32)
    weight = torch.as_tensor(demos.weight, dtype=torch.float32)
    rows: list[dict[str, float]] = []
    for _ in range(int(epochs)):
        order = rng.permutation(len(obs))
        for start in range(0, len(order), batch_size):
            b = torch.as_tensor(order[start:start + batch_size])
            values, log_prob, _ = policy.evaluate_actions(obs[b], act[b])
            w = weight[b] / weight[b].sum().clamp(min=1e-12)
            actor = -(w * log_prob).sum()
            critic = (w * F.mse_loss(values.flatten(), rew[b], reduction="none")).sum()
            loss = actor + model.vf_coef * critic if mode == "actor_critic" else actor
            policy.optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), model.max_grad_norm)
            policy.optimizer.step()
            rows.append({"actor_loss": actor.item(), "critic_loss": critic.item(),
                         "expert_prob": float(log_prob.detach().exp().mean())})
            if on_batch is not None:
                on_batch(len(rows) - 1, rows[-1])
    policy.set_training_mode(False)
    return rows


def curve_callback(on_update: Callable[[dict[str, float]], None] | None = None, progress: bool = True,
                   total: int | None = None, desc: str = "LN") -> Any:
    """An SB3 callback that turns every A2C update into one row: ``timesteps``, ``frames`` (physics frames so
    far), ``success_rate`` and ``reward`` (mean over the episodes that ended in the update's rollout; 0 when none
    did), ``window_success_rate`` (over the last update's worth of episodes ended so far, ``n_steps x n_envs``:
    a joint-control episode spans several updates), ``episodes``, ``errors``, and the update's ``policy_loss``, ``value_loss``,
    ``entropy``. Rows go to ``on_update`` and to the callback's ``rows``."""
    from stable_baselines3.common.callbacks import BaseCallback  # heavy: torch (stable-baselines3)
    from tqdm.auto import tqdm

    class Curve(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.rows: list[dict[str, float]] = []
            self._episodes: list[dict[str, Any]] = []
            self._window: deque[bool] = deque()
            self._pending: dict[str, float] | None = None
            self._frames = 0
            self._bar: Any = None

        def _on_training_start(self) -> None:
            self._window = deque(maxlen=self.model.n_steps * self.model.n_envs)  # one update's worth
            self._bar = tqdm(total=total, desc=desc, unit="plan", disable=not progress)

        def _on_step(self) -> bool:
            for info, done in zip(self.locals["infos"], self.locals["dones"], strict=True):
                if done:
                    self._episodes.append(info)
                    self._frames += int(info.get("frames", 0))
            self._bar.update(len(self.locals["dones"]))
            return True

        def _on_rollout_start(self) -> None:
            self._finish_pending()

        def _on_rollout_end(self) -> None:
            eps, self._episodes = self._episodes, []
            self._window.extend(bool(e.get("success", False)) for e in eps)
            self._pending = {
                "timesteps": float(self.num_timesteps), "frames": float(self._frames),
                "success_rate": float(np.mean([e.get("success", False) for e in eps])) if eps else 0.0,
                "reward": float(np.mean([e.get("measure", 0.0) for e in eps])) if eps else 0.0,
                "window_success_rate": float(np.mean(self._window)) if self._window else 0.0,
                "episodes": float(len(eps)), "errors": float(sum(bool(e.get("error")) for e in eps)),
            }
            self._bar.set_postfix(success=f"{self._pending['success_rate']:.2f}")

        def _on_training_end(self) -> None:
            self._finish_pending()
            self._bar.close()

        def _finish_pending(self) -> None:
            if self._pending is None:
                return
            values = self.model.logger.name_to_value
            row = dict(self._pending)
            for ours, theirs in (("policy_loss", "train/policy_loss"), ("value_loss", "train/value_loss"),
                                 ("entropy", "train/entropy_loss")):
                if theirs in values:
                    row[ours] = float(-values[theirs] if ours == "entropy" else values[theirs])
            self._pending = None
            self.rows.append(row)
            if on_update is not None:
                on_update(row)

    return Curve()


def train_ln(model: Any, timesteps: int, on_update: Callable[[dict[str, float]], None] | None = None,
             progress: bool = True, desc: str = "LN") -> list[dict[str, float]]:
    """Run A2C for ``timesteps`` environment steps (plan episodes); one row per update (``curve_callback``)."""
    if timesteps == 0:
        return []
    callback = curve_callback(on_update, progress, timesteps, desc)
    model.learn(total_timesteps=int(timesteps), callback=callback, log_interval=None)
    return callback.rows


def predict_plans(policy: Any, x: np.ndarray) -> np.ndarray:
    """(N, 6) deterministic plans (per-dimension argmax) of an A2C policy for (N, D) inputs."""
    actions, _ = policy.predict(np.asarray(x, np.float32), deterministic=True)
    return np.asarray(actions, np.int64).reshape(len(x), -1)


def ln_policy(policy: Any, pointnet: Any, task_name: str, texts: Sequence[str], seeds: Sequence[int], n_points: int):
    """An ``envs.trials.Policy`` executing the LN's deterministic plan for the live scene's x."""
    from prl.features import scene_features  # heavy: trimesh

    def choose(i: int, env: Any, x_manip: np.ndarray) -> list[int]:
        x = scene_features(task_name, int(seeds[i]), dict(env.scene_params), x_manip, texts[i % len(texts)],
                           pointnet, n_points)
        return predict_plans(policy, x)[0].tolist()

    return choose


def save_ln(model: Any, path: str | Path) -> Path:
    """Save the A2C as SB3's zip at ``path`` (which must end in .zip); returns ``path``."""
    path = Path(path)
    if path.suffix != ".zip":
        raise ValueError(f"an LN checkpoint is an SB3 zip; {str(path)!r} does not end in .zip")
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(str(path))
    return path


def load_ln(path: str | Path) -> Any:
    """The A2C saved at ``path``; ``FileNotFoundError`` naming it when missing."""
    from stable_baselines3 import A2C  # heavy: torch (stable-baselines3)

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no LN checkpoint at {str(path)!r}")
    return A2C.load(str(path), device="cpu")
