"""Ending decided failures early (``ExecutorConfig.end_decided``): the same failure in fewer frames, successes in
full, and the decision reads the simulation without changing it."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from envs.execution import ExecutorConfig

DECIDED = {
    "hammer": (1631670582, (2, 5, 3, 0, 0, 1)),
    "sweep": (1157705724, (2, 4, 3, 3, 0, 3)),
    "tweeze": (1881498831, (3, 3, 2, 0, 4, 1)),
}
"""(scene seed, plan) of prior-sampled synthesis attempts (run seed 0, shard 0: hammer attempt 17, sweep 26, tweeze
15) whose failure is decided before the end: the hammer, and the broom, slip out of the hand and lie asleep far
from where the hand goes next by the end of the transport; the little finger's metacarpal presses on the cube
during the approach."""
EXPERT_SEED = 0
"""A scene where each task's expert plan succeeds."""
RECORDED = ("frame", "stage", "qpos", "qvel", "target", "force", "contact_pos", "contact_normal", "palm_pose",
            "tool_pose", "object_pose", "scene_pose", "scene_qpos")


def test_end_decided_must_be_a_bool() -> None:
    with pytest.raises(TypeError, match="end_decided"):
        ExecutorConfig(end_decided="yes")


def test_capsule_clearance_is_exact() -> None:
    from envs.reach import capsule_clearance  # heavy: the kinematics (torch)
    from prl.geometry import segment_distance

    rng = np.random.default_rng(0)
    for k in range(50):
        a = np.concatenate([rng.normal(size=(40, 6)) * 0.2, rng.uniform(0.0, 0.05, (40, 1))], axis=1)
        b = np.concatenate([rng.normal(size=(6, 6)) * 0.2 + 0.3, rng.uniform(0.0, 0.05, (6, 1))], axis=1)
        if k % 2:
            a[:, 3:6] = a[:, 0:3]  # spheres
        brute = segment_distance(a[:, None, :3], a[:, None, 3:6], b[None, :, :3], b[None, :, 3:6])
        assert capsule_clearance(a, b) == pytest.approx(float(np.min(brute - a[:, None, 6] - b[None, :, 6])), abs=1e-12)
    assert capsule_clearance(a[:0], b) == np.inf


def _both(make_task_env: Any, task: str, plan: Any, seed: int) -> tuple[Any, Any, Any]:
    from envs.executor import PlanExecutor  # heavy: loads the simulator

    env = make_task_env(task)
    full = PlanExecutor(env).run(plan, seed=seed)
    early = PlanExecutor(env, ExecutorConfig(end_decided=True)).run(plan, seed=seed)
    return env, full, early


@pytest.mark.sim
@pytest.mark.parametrize("task", sorted(DECIDED))
def test_a_decided_failure_ends_early_with_the_same_failure(make_task_env: Any, task: str) -> None:
    seed, plan = DECIDED[task]
    env, full, early = _both(make_task_env, task, plan, seed)
    n = int(env.stages.stage_frames(750).sum())
    assert not full.success and not early.success
    assert full.decided == "" and "decided" not in full.outcome and full.frames_stepped == n
    assert early.decided and early.outcome["decided"] == early.decided and early.outcome["success"] is False
    assert early.frames_stepped < n and early.frame[-1] < early.frames_stepped
    assert early.fps > 0 and not early.fault
    # the decisions only read the scene: what was recorded up to the early end is the full episode's record
    k = len(early.frame)
    for name in RECORDED:
        assert np.array_equal(getattr(early, name), getattr(full, name)[:k]), name


@pytest.mark.sim
@pytest.mark.parametrize("task", sorted(DECIDED))
def test_a_success_runs_in_full_and_unchanged(make_task_env: Any, task: str) -> None:
    from envs.tasks import task_class  # heavy: loads the simulator

    env, full, early = _both(make_task_env, task, task_class(task).expert_plan, EXPERT_SEED)
    assert full.success and early.success
    assert early.decided == "" and early.frames_stepped == full.frames_stepped == int(env.stages.stage_frames(750).sum())
    assert early.outcome == full.outcome
    for name in RECORDED:
        assert np.array_equal(getattr(early, name), getattr(full, name)), name


@pytest.mark.sim
def test_the_hand_reach_measures_clearance_and_knows_when_it_cannot(make_task_env: Any) -> None:
    from envs.reach import (  # heavy: the kinematics (torch)
        HandReach,
        body_capsules,
        capsule_clearance,
        hand_capsules,
        moving_bodies,
    )

    env = make_task_env("hammer")
    env.reset(seed=EXPERT_SEED)
    bodies = moving_bodies(env)
    names = {b.entity.name for b in bodies}
    assert any("hammer" in name for name in names) and any("nail_head" in name for name in names)
    assert not any(word in name for name in names for word in ("board", "rack", "table", "nail_base"))
    art = env.agent.robot._objs[0]
    root = np.asarray(art.get_root_pose().to_transformation_matrix())
    q = np.asarray(art.get_qpos(), dtype=np.float64)[env.agent.joint_perm]
    assert HandReach(env, lambda: None, root).clearance(bodies) == -np.inf  # the path is not known yet
    here = HandReach(env, lambda: np.stack([q, q]), root)
    direct = capsule_clearance(hand_capsules(env, q[None], root), np.concatenate([body_capsules(b) for b in bodies]))
    assert 0.0 < here.clearance(bodies) <= direct + 1e-9
    lowered = q.copy()
    lowered[2] -= 1.0  # the arm's Z slide a metre down: through the table and the hammer on its rack
    assert not HandReach(env, lambda: np.stack([q, lowered]), root).clear_of(bodies)
    assert here.clearance([]) == np.inf
