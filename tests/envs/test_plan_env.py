"""The LN's environments: one whole plan per step (``envs.plan_env``), 30-D joint control (``envs.joint_env``),
on the scene stream of ``envs.scene_stream``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


@pytest.mark.sim
def test_plan_env_executes_one_plan_per_terminal_step(pointnet_path: Path) -> None:
    from envs.plan_env import PlanEnv
    from envs.scene_stream import ln_scene_seed
    from envs.tasks import task_class

    env = PlanEnv("hammer", pointnet_path, n_points=64, run_seed=5)
    try:
        assert env.action_space.nvec.tolist() == list(env.plb.sizes) and env.observation_space.shape == (1680,)
        with pytest.raises(RuntimeError, match="before reset"):
            env.step(task_class("hammer").expert_plan)
        x, info = env.reset()
        assert x.shape == (1680,) and np.all(np.isfinite(x)) and info["scene_seed"] == ln_scene_seed(5, 0, 0)
        with pytest.raises(ValueError, match="7"):
            env.step([7, 0, 0, 0, 0, 0])  # a0 has 7 choices: 0..6
        _, reward, terminated, truncated, info = env.step(task_class("hammer").expert_plan)
        sim = env._env.unwrapped.evaluate()  # the reward is the simulated nail descent, read after the episode
        assert terminated and not truncated
        assert reward == pytest.approx(float(sim["nail_descent_cm"][0]), abs=1e-6) and reward > 0.5
        assert info["success"] and info["measure"] == reward and info["frames"] > 700
        x2, info2 = env.reset()  # the next scene of the stream
        assert info2["scene_seed"] == ln_scene_seed(5, 0, 1) and not np.array_equal(x, x2)
        _, reward2, *_ = env.step([6, 6, 5, 3, 6, 5])  # wrong in every dimension
        assert reward2 < 0.05
        x3, _ = env.reset(options={"scene_seed": ln_scene_seed(5, 0, 0)})  # the same scene again: the same x
        np.testing.assert_allclose(x3, x, atol=1e-5)
    finally:
        env.close()


@pytest.mark.sim
def test_joint_env_takes_150_steps_of_10_frames() -> None:
    from envs.joint_env import JointControlEnv

    env = JointControlEnv("hammer", run_seed=1)
    try:
        assert env.action_space.shape == (30,)
        obs, _ = env.reset()
        assert obs.shape == env.observation_space.shape and obs[-1] == 0.0
        rng = np.random.default_rng(0)
        total, dones = 0.0, []
        for _ in range(150):
            obs, reward, terminated, truncated, info = env.step(rng.uniform(-0.05, 0.05, 30))
            total += reward
            dones.append(terminated)
            assert not truncated
        assert dones == [False] * 149 + [True]
        assert env._env.unwrapped.elapsed_steps.item() * 5 == 1500 and info["frames"] == 1500
        assert total == pytest.approx(info["measure"], abs=1e-6)  # the return is the task's measure at the end
        with pytest.raises(ValueError, match="30 values"):
            env.step(np.zeros(29))
    finally:
        env.close()
