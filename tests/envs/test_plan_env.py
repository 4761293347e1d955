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
def test_joint_env_takes_150_steps_of_5_frames_at_the_datasets_rate() -> None:
    from envs.joint_env import JointControlEnv, observation_parts
    from prl.env_state import ENV_STATE_DIM

    env = JointControlEnv("hammer", run_seed=1)
    try:
        assert env.action_space.shape == (30,) and env.frames_per_step == 5 and env.steps == 150
        obs, _ = env.reset()
        assert obs.shape == env.observation_space.shape == (60 + ENV_STATE_DIM + 1,) and obs[-1] == 0.0
        u = env._env.unwrapped
        parts = observation_parts(obs)
        np.testing.assert_allclose(parts["observation.state"][:30], u.agent.named_qpos(), atol=1e-6)
        np.testing.assert_allclose(parts["observation.environment_state"][:3], u.tool.pose.p[0].numpy(), atol=1e-6)
        rng = np.random.default_rng(0)
        total, dones = 0.0, []
        for _ in range(150):
            obs, reward, terminated, truncated, info = env.step(rng.uniform(-0.05, 0.05, 30))
            total += reward
            dones.append(terminated)
            assert not truncated
        assert dones == [False] * 149 + [True] and info["frames"] == 750 and obs[-1] == 1.0
        assert total == pytest.approx(info["measure"], abs=1e-6)  # the return is the task's measure at the end
        with pytest.raises(ValueError, match="30 values"):
            env.step(np.zeros(29))
    finally:
        env.close()


def _joints_outside_their_own_limits(targets_low: np.ndarray, targets_high: np.ndarray, robot: object) -> list[str]:
    """The joints (``JOINT_NAMES`` order targets) whose -1 / +1 targets are not their own limits, looked up by name."""
    from prl.constants import JOINT_NAMES

    names = [j.name for j in robot.active_joints]
    limits = robot.get_qlimits()[0].cpu().numpy()
    return [n for i, n in enumerate(JOINT_NAMES) if not np.allclose(
        [targets_low[i], targets_high[i]], limits[names.index(n)], atol=1e-6)]


@pytest.mark.sim
@pytest.mark.parametrize("task", ["hammer", "sweep", "unscrew", "tweeze"])
def test_joint_actions_command_each_joint_in_its_own_range(task: str) -> None:
    """-1 and +1 on every action component give each joint's own lower and upper limit, by name; the former mapping
    (the articulation's limits in its own order, applied in ``JOINT_NAMES`` order) fails the same check."""
    from envs.joint_env import JointControlEnv

    env = JointControlEnv(task)
    try:
        robot = env._env.unwrapped.agent.robot
        low, high = env.target_of(-np.ones(30)), env.target_of(np.ones(30))
        assert _joints_outside_their_own_limits(low, high, robot) == []
        old = robot.get_qlimits()[0].cpu().numpy()  # articulation order: what the env used to apply
        wrong = _joints_outside_their_own_limits(old[:, 0], old[:, 1], robot)
        assert len(wrong) >= 10 and "FFJ3" in wrong
    finally:
        env.close()
