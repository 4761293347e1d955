"""ManiSkill's state API (what its trajectory replay and state resets use) on every registered PRL task:
``get_state``/``set_state`` (flat) and ``get_state_dict``/``set_state_dict`` restore the observation, also after
the scene was rebuilt with other bodies (a sweep's cube count changes with the seed) and on a scene with no free
actor (the bottle), and the per-frame watch's state (what the hammer drove, the unscrew's motion start) with it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from envs.tasks.base import state_size, unflatten_state

pytestmark = pytest.mark.sim


def flat_obs(env) -> np.ndarray:
    from mani_skill.utils.common import flatten_state_dict  # heavy: loads the simulator

    return flatten_state_dict(env.get_obs(), use_torch=True).cpu().numpy().ravel()


def test_unflatten_reads_what_flatten_wrote() -> None:
    from mani_skill.utils.common import flatten_state_dict  # heavy: loads the simulator

    layout = {"actors": {"a": torch.arange(13.0)[None]}, "articulations": {},
              "task": {"x": torch.tensor([[7.0]]), "y": torch.tensor([[8.0]])}}
    flat = flatten_state_dict(layout, use_torch=True)
    assert state_size(layout) == 15 and flat.shape == (1, 15)
    back, end = unflatten_state(flat, layout)
    assert end == 15 and back["task"]["y"].item() == 8.0 and back["actors"]["a"][0, 12].item() == 12.0


# task, the expert-like plan run before the state is taken, (seed, other seed with other bodies)
CASES = [("hammer", 3, 4), ("sweep", 0, 2), ("unscrew", 0, 1), ("tweeze", 1, 2)]  # sweep: 8 cubes, then 6


@pytest.mark.parametrize(("task", "seed", "other"), CASES)
def test_state_round_trips_after_the_scene_was_rebuilt(task: str, seed: int, other: int, make_task_env) -> None:
    from envs.executor import PlanExecutor  # heavy: loads the simulator

    env = make_task_env(task)
    result = PlanExecutor(env).run(type(env).expert_plan, seed=seed)
    assert result.success  # a state worth restoring: the watch has something to remember
    obs, flat, state, watch = flat_obs(env), env.get_state(), env.get_state_dict(), env.watch_state()
    assert set(state) >= {"actors", "articulations"}
    env.reset(seed=other)
    if task == "sweep":  # another seed, other cubes: the flat layout differs, and a wrong vector is refused
        assert env.get_state().shape != flat.shape, "pick seeds with different cube counts"
        with pytest.raises(ValueError, match=f"a flat state of {flat.shape[-1]} values"):
            env.set_state(flat)
    for restore in (lambda: env.set_state(flat), lambda: env.set_state_dict(state)):
        env.reset(seed=seed)
        assert not np.allclose(flat_obs(env), obs)  # a fresh scene: the episode's state is gone
        restore()
        np.testing.assert_allclose(flat_obs(env), obs, atol=1e-5)
        assert env.watch_state() == pytest.approx(watch)


def test_the_grasp_probe_round_trips(make_task_env) -> None:
    from envs.tasks.grasp_probe import make_probe_env  # heavy: loads the simulator

    gym_env = make_probe_env("handle")
    try:
        env = gym_env.unwrapped
        env.reset(seed=2)
        for _ in range(50):
            env.step_physics()
        obs, flat = flat_obs(env), env.get_state()
        env.reset(seed=2)
        env.set_state(flat)
        np.testing.assert_allclose(flat_obs(env), obs, atol=1e-5)
    finally:
        gym_env.close()


def test_bad_watch_state_is_named(make_task_env) -> None:
    env = make_task_env("hammer")
    with pytest.raises(ValueError, match="unknown hammer watch state \\['nail'\\]"):
        env.set_watch_state({"nail": 1.0})


def test_the_registry_lists_the_pipeline_tasks_from_their_modules() -> None:
    """Every module of ``envs/tasks`` registers itself; the paper's four come first in their order, the grasp
    probe (``pipeline_task = False``) is not a task, and an unknown name is an error naming it."""
    from envs.tasks import TASK_ENV_IDS, task_class

    assert list(TASK_ENV_IDS)[:4] == ["hammer", "sweep", "unscrew", "tweeze"]
    assert TASK_ENV_IDS["unscrew"] == "PRL-Unscrew-v1" and "grasp_probe" not in TASK_ENV_IDS
    assert all(task_class(t).task_name == t for t in TASK_ENV_IDS)
    with pytest.raises(ValueError, match="unknown task 'grasp_probe'"):
        task_class("grasp_probe")
