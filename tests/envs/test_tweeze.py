"""PRL-Tweeze-v1: the hinge spring holds the tweezers open and reopens them, the same seed builds the same scene
and gives the same outcome, and physics decides: a pinch that shuts the tips carries the cube up, fingers that do
not close never lift it, and a cube the hand touched at any time does not count."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import prl.shapes as S

EXPERT = (2, 1, 4, 2, 6, 1)


def test_tweezers_and_cube_meshes_match_hand_computed_bounds() -> None:
    tweezers, cube = S.scene_meshes("tweeze", {"arm_length": 0.16, "tip_gap": 0.04, "cube_size": 0.02})
    # in the root link's frame (half a turn about Y from the tweezers' own): arms 16 cm along -X from the hinge,
    # opening to 4 cm between the inner faces (+ 3 mm each outside) at the tips; 1.2 cm tall; the 1.2 cm butt
    # block behind the hinge, along +X
    half_angle = np.arcsin(0.04 / 0.32)
    z_max = 0.16 * np.sin(half_angle) + 0.003 * np.cos(half_angle)
    np.testing.assert_allclose(tweezers.bounds[:, 1], [-0.006, 0.006], atol=1e-6)
    np.testing.assert_allclose(tweezers.bounds[:, 2], [-z_max, z_max], atol=1e-4)
    assert tweezers.bounds[1, 0] == pytest.approx(0.012, abs=1e-6)
    assert tweezers.bounds[0, 0] == pytest.approx(-0.16 * np.cos(half_angle), abs=1e-6)  # the tips' inner corners
    np.testing.assert_allclose(cube.bounds, [[-0.01, -0.01, 0.0], [0.01, 0.01, 0.02]], atol=1e-9)


@pytest.fixture(scope="module")
def env(make_task_env):
    return make_task_env("tweeze")


@pytest.mark.sim
def test_same_seed_same_scene_and_the_spring_holds_the_tips_open(env) -> None:
    env.reset(seed=4)
    first = dict(env.scene_params)
    for _ in range(250):  # 1 s untouched
        env.scene.step()
    assert abs(env.tweezers_opening()) < 0.005 and env.cube_between_tips()
    assert float(env.cube_lift_cm()[0]) == pytest.approx(0.0, abs=0.05)
    env.reset(seed=4)
    assert env.scene_params == first
    env.reset(seed=5)
    assert env.scene_params != first


@pytest.mark.sim
def test_the_spring_reopens_the_tweezers_when_released(env) -> None:
    env.reset(seed=6)
    tool_p = env.tool.pose.raw_pose.numpy()[0, :3]
    for _ in range(250):  # pinch the two tips together with 1 N each for 1 s (opposite forces: no net push)
        for body, side in ((env.arm_b._bodies[0], 1.0), (env.tool._bodies[0], -1.0)):
            pose = body.get_entity_pose()
            rotation = pose.to_transformation_matrix()[:3, :3] @ S.TWEEZERS_LINK_IN_FRAME.T  # the tweezers' frame
            across = rotation[:, 2]  # the tweezers' Z (from arm a to arm b)
            tip = np.asarray(pose.p) + rotation @ np.array([env.scene_params["arm_length"] * 0.9, 0.0, 0.0])
            body.add_force_at_point(-side * 1.0 * across, tip)
        env.scene.step()
    closed = env.tweezers_opening()
    assert closed > 0.05
    for _ in range(500):  # released for 2 s
        env.scene.step()
    assert env.tweezers_opening() < 0.2 * closed
    assert np.linalg.norm(env.tool.pose.raw_pose.numpy()[0, :3] - tool_p) < 0.05  # still on its rack


@pytest.mark.sim
def test_a_pinch_lifts_the_cube_by_the_tips_and_open_fingers_never_do(env, monkeypatch) -> None:
    from honesty import no_state_writes

    from envs.executor import PlanExecutor
    from prl import stages

    executor = PlanExecutor(env)
    executor.observe(seed=1)
    with no_state_writes(monkeypatch) as writes:  # nothing sets a pose or joint state of tweezers or cube
        result = executor.run(EXPERT)
    assert writes == []
    assert result.success and result.outcome["cube_lift_cm"] > 10.0
    assert result.outcome["between_tips"] and not result.outcome["hand_touches_cube"]
    assert env.tweezers_opening() > 0.05  # held shut on the cube by the fingers
    assert executor.run(EXPERT, seed=1).outcome == result.outcome  # same scene, same plan: the same outcome
    # without the twist, the same pinch lifts the cube as high, but on the way up the palm's little-finger side
    # brushes it (and lets go of it by the end): not a success
    result = executor.run((0, 3, 4, 2, 6, 0), seed=0)
    assert result.outcome["cube_lift_cm"] > 10.0 and result.outcome["hand_touches_cube"] and not result.success
    assert env.hand_touches_cube() == [] and env.hand_touched_cube() == ["lf_metacarpal"]
    # fingers that keep their open posture through the grasp never lift the cube
    pinch = stages.GRASP_POSTURES["palmar_pinch"]
    monkeypatch.setitem(stages.GRASP_POSTURES, "palmar_pinch", replace(pinch, closed=pinch.open.copy()))
    monkeypatch.setitem(stages.MOTION_AMPLITUDES, "finger_squeeze", 0.0)
    for seed in (0, 1):
        result = executor.run(EXPERT, seed=seed)
        assert result.outcome["cube_lift_cm"] < 1.0 and not result.success


@pytest.mark.sim
def test_bad_plans_and_task_names_get_clear_errors(env) -> None:
    from envs.executor import PlanExecutor
    from envs.tasks import make_env
    from prl.plb import PLBError

    executor = PlanExecutor(env)
    env.reset(seed=3)
    before, params = env.tweezers.pose.raw_pose.clone(), dict(env.scene_params)
    with pytest.raises(PLBError, match=r"plan entry for grasp_pattern is 9, out of range; allowed 0..3"):
        executor.run((2, 1, 4, 9, 6, 0), seed=4)
    with pytest.raises(PLBError, match=r"plan must have 6 entries"):
        executor.run((2, 1, 4, 2, 6), seed=4)
    # refused before the reset: scene 3 is still there, untouched (scene 4 would have other parameters)
    assert env.scene_params == params and (env.tweezers.pose.raw_pose == before).all()
    with pytest.raises(ValueError, match=r"unknown task 'tweezer'; known tasks: .*'tweeze'"):
        make_env("tweezer")
