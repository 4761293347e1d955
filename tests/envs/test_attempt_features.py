"""x of a synthesis attempt, rebuilt from its seed (envs.attempt_features), is the x its plan was chosen on."""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.sim


def test_attempt_x_is_the_observed_scene_of_the_plan_run(pointnet_path):
    from envs.attempt_features import attempt_features
    from envs.executor import PlanExecutor
    from envs.tasks import fast_resets, make_env, task_class
    from prl.features import scene_features
    from prl.plb import load_plb
    from prl.pointnet import load_pointnet

    task, seeds = "hammer_mixed", [3, 4]
    pointnet = load_pointnet(pointnet_path)
    x, params = attempt_features(task, seeds, pointnet, 64, progress=False)
    assert x.shape == (2, 1680) and params[0] != params[1]
    with fast_resets():
        env = make_env(task)
        try:
            result = PlanExecutor(env).run(task_class(task).expert_plan, seed=seeds[1])
            live = dict(env.unwrapped.scene_params)
        finally:
            env.close()
    # the plan's own observation phase gave the same x_manip, and the scene the same values (its family too)
    np.testing.assert_array_equal(x[1, :784], result.x_manip)
    assert params[1] == live and "family" in live
    # and the rest of x is the live scene's (PointNet and text encoded in one batch here: float32 rounding apart)
    texts = load_plb().texts(task)
    np.testing.assert_allclose(x[1], scene_features(task, seeds[1], live, result.x_manip, texts[1], pointnet, 64)[0],
                               rtol=1e-4, atol=1e-6)
