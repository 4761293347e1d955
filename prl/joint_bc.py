"""Behaviour cloning of the joint-space actor (the LN method ``joint_bc``, DAPG's protocol): before A2C on joint
targets (``envs.joint_env``), the actor is trained to give the demonstrations' joint actions the highest likelihood
and the critic to predict their discounted returns under the joint-control environment's own reward.

The demonstrations are the dataset episodes of the same K draws as the plan-space points (``prl.imitation``), each
replayed open loop in the joint-control environment (``envs.replay.replayed_demonstrations``): its observations
are the environment's (the state before each step), its actions the recorded ``action`` rows mapped back onto
[-1, 1] per joint (``actions_of_targets``, the inverse of ``JointControlEnv.target_of``), its rewards what the
environment paid for each step (the change of the task's measure; no stage is announced, as in the environment's
own episodes), its returns their discounted sums to the episode's end (``returns_to_go``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class JointDemonstrations:
    """Joint-space transitions for pre-training: one per step of each replayed demonstration."""

    obs: np.ndarray
    """(N, D) float32 joint-control observations, before each step."""
    action: np.ndarray
    """(N, 30) float32 actions in [-1, 1] (``actions_of_targets`` of the recorded joint targets)."""
    ret: np.ndarray
    """(N,) float32 discounted returns from each step to the episode's end."""

    def __post_init__(self) -> None:
        n = len(self.obs)
        if self.obs.ndim != 2 or self.action.shape[:1] != (n,) or self.action.ndim != 2 or self.ret.shape != (n,):
            raise ValueError(f"joint demonstrations must be obs (N, D), action (N, A), ret (N,); got "
                             f"{self.obs.shape}, {self.action.shape}, {self.ret.shape}")
        if not (np.all(np.isfinite(self.obs)) and np.all(np.isfinite(self.action)) and np.all(np.isfinite(self.ret))):
            raise ValueError("joint demonstrations hold non-finite values")


def actions_of_targets(targets: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The actions in [-1, 1] whose joint targets (``JointControlEnv.target_of``: ``low + (a + 1) / 2 * (high -
    low)``) are ``targets`` (..., 30), clipped to the joints' limits. ValueError naming a joint whose range is empty."""
    low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
    span = high - low
    if np.any(span <= 0):
        raise ValueError(f"joint ranges must be positive, got {span.round(4).tolist()}")
    return np.clip(2.0 * (np.asarray(targets, np.float64) - low) / span - 1.0, -1.0, 1.0)


def returns_to_go(rewards: Sequence[float], gamma: float) -> np.ndarray:
    """``G_t = r_t + gamma * G_{t+1}`` of one episode's rewards, to its end (no bootstrap: the episode ends there)."""
    out = np.zeros(len(rewards), np.float64)
    running = 0.0
    for t in range(len(rewards) - 1, -1, -1):
        running = float(rewards[t]) + gamma * running
        out[t] = running
    return out


def pretrain_joint(model: Any, demos: JointDemonstrations, epochs: int, batch_size: int | None = None,
                   seed: int = 0) -> list[dict[str, float]]:
    """Train ``model``'s policy (an A2C of ``prl.ln.make_ln`` on the joint-control environment) on ``demos`` in
    minibatches of ``batch_size`` (None: one A2C update's samples) with its own optimizer: the actor's negative
    log-likelihood of the demonstrated actions plus ``vf_coef`` times the critic's squared error on their returns.
    One row per minibatch: ``actor_loss``, ``critic_loss``, ``action_error`` (mean |deterministic action -
    demonstrated action|). ValueError naming a shape the model does not take."""
    import torch  # heavy: torch (stable-baselines3)
    import torch.nn.functional as F

    dim, width = model.observation_space.shape[0], model.action_space.shape[0]
    if demos.obs.shape[1] != dim or demos.action.shape[1] != width:
        raise ValueError(f"joint demonstrations of obs {demos.obs.shape[1]} and action {demos.action.shape[1]} "
                         f"values; the model observes {dim} and acts on {width}")
    if not len(demos.obs):
        return []
    batch_size = int(batch_size or model.n_steps * model.n_envs)
    policy = model.policy
    policy.set_training_mode(True)
    rng = np.random.default_rng(seed)
    obs = torch.as_tensor(demos.obs, dtype=torch.float32)
    act = torch.as_tensor(demos.action, dtype=torch.float32)
    ret = torch.as_tensor(demos.ret, dtype=torch.float32)
    rows: list[dict[str, float]] = []
    for _ in range(int(epochs)):
        order = rng.permutation(len(obs))
        for start in range(0, len(order), batch_size):
            b = torch.as_tensor(order[start:start + batch_size])
            values, log_prob, _ = policy.evaluate_actions(obs[b], act[b])
            actor = -log_prob.mean()
            critic = F.mse_loss(values.flatten(), ret[b])
            loss = actor + model.vf_coef * critic
            policy.optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), model.max_grad_norm)
            policy.optimizer.step()
            with torch.no_grad():
                mean = policy.get_distribution(obs[b]).distribution.mean
            rows.append({"actor_loss": actor.item(), "critic_loss": critic.item(),
                         "action_error": float((mean.clamp(-1, 1) - act[b]).abs().mean())})
    policy.set_training_mode(False)
    return rows
