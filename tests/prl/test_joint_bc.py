"""Behaviour cloning of the joint-space actor (``prl.joint_bc``): the inverse of the joint env's action map, the
returns, and pre-training that moves an A2C's Gaussian actor onto demonstrated actions and its critic onto their
returns (a toy environment, no simulator)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from prl.joint_bc import JointDemonstrations, actions_of_targets, returns_to_go


def test_actions_invert_the_joint_envs_map_and_clip() -> None:
    low, high = np.array([-0.26, 0.0, -1.0]), np.array([1.57, 0.5, 1.0])
    a = np.array([[-1.0, 0.2, 0.5], [1.0, -0.6, 0.0]])
    targets = low + (a + 1.0) / 2.0 * (high - low)  # JointControlEnv.target_of
    np.testing.assert_allclose(actions_of_targets(targets, low, high), a, atol=1e-12)
    assert actions_of_targets(np.array([2.0, -1.0, 0.0]), low, high).tolist() == [1.0, -1.0, 0.0]  # beyond: clipped
    with pytest.raises(ValueError, match="joint ranges must be positive"):
        actions_of_targets(targets, high, low)


def test_returns_to_go_by_hand() -> None:
    # rewards 1, 0, 2 with gamma 0.5: G2 = 2, G1 = 0 + 0.5 * 2 = 1, G0 = 1 + 0.5 * 1 = 1.5
    np.testing.assert_allclose(returns_to_go([1.0, 0.0, 2.0], 0.5), [1.5, 1.0, 2.0])
    assert returns_to_go([0.25, 0.5, 0.25], 1.0)[0] == 1.0  # undiscounted: the episode's measure
    assert returns_to_go([], 0.9).shape == (0,)


def test_malformed_demonstrations_are_named() -> None:
    with pytest.raises(ValueError, match="obs \\(N, D\\), action \\(N, A\\), ret \\(N,\\)"):
        JointDemonstrations(np.zeros((3, 4), np.float32), np.zeros((2, 30), np.float32), np.zeros(3, np.float32))
    with pytest.raises(ValueError, match="non-finite"):
        JointDemonstrations(np.full((1, 4), np.nan, np.float32), np.zeros((1, 30), np.float32), np.zeros(1))


class Toy(gym.Env):
    """Observations in R^4, actions in [-1, 1]^3: the shape of the joint-control env, without the simulator."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (3,), np.float32)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        return np.zeros(4, np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        return np.zeros(4, np.float32), 0.0, True, False, {}


def test_pretraining_moves_the_actor_onto_the_demonstrated_actions_and_the_critic_onto_their_returns() -> None:
    """Two kinds of state, each with its own action and return: after cloning, the deterministic action of each
    is within 0.1 of its demonstrated one (at initialisation about 0.5 away) and the critic within 0.1 of its
    return."""
    import torch

    from prl.config import LNConfig
    from prl.joint_bc import pretrain_joint
    from prl.ln import make_ln

    rng = np.random.default_rng(0)
    kind = rng.integers(0, 2, 512)
    obs = np.stack([kind, 1 - kind, kind * 0.5, np.ones_like(kind)], axis=1).astype(np.float32)
    want = np.array([[0.6, -0.4, 0.2], [-0.5, 0.5, -0.3]], np.float32)
    demos = JointDemonstrations(obs, want[kind], np.where(kind == 1, 2.0, -1.0).astype(np.float32))
    model = make_ln(Toy(), LNConfig(hidden=(32, 32), learning_rate=3e-3))

    def errors() -> tuple[float, float]:
        with torch.no_grad():
            mean = model.policy.get_distribution(torch.as_tensor(obs)).distribution.mean.numpy()
            value = model.policy.predict_values(torch.as_tensor(obs)).numpy().ravel()
        return float(np.abs(mean - demos.action).mean()), float(np.abs(value - demos.ret).mean())

    before = errors()
    rows = pretrain_joint(model, demos, epochs=60, batch_size=64, seed=0)
    after = errors()
    assert before[0] > 0.3 and after[0] < 0.1, (before, after)
    assert after[1] < 0.1 < before[1], (before, after)
    assert len(rows) == 60 * 8 and rows[-1]["action_error"] < rows[0]["action_error"]
    with pytest.raises(ValueError, match="the model observes 4 and acts on 3"):
        pretrain_joint(model, JointDemonstrations(obs[:, :3], want[kind], demos.ret), epochs=1)
