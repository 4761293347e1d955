"""PRL-Sweep-v1: seeded scenes, cubes that start outside the zone, success read from simulated cube
positions, and physics deciding which plans sweep (expert yes, wrong plan and open fingers no)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import prl.shapes as S

EXPERT = (0, 3, 2, 0, 2, 0)


def test_broom_and_debris_meshes_match_hand_computed_bounds() -> None:
    broom = S.sweep_tool_mesh({"handle_radius": 0.01, "handle_half_length": 0.1, "head_half_x": 0.02,
                               "head_half_y": 0.01, "head_half_z": 0.05})
    # capsule x in [-0.11, 0.11]; head box centred at x = -0.12: x in [-0.14, -0.10], z in [-0.05, 0.05]
    np.testing.assert_allclose(broom.bounds, [[-0.14, -0.01, -0.05], [0.11, 0.01, 0.05]], atol=1e-4)
    debris = S.sweep_object_mesh({"n_cubes": 1, "line_x": 0.3, "line_y": 0.1, "cube0_size": 0.02, "cube0_yaw": 0.0,
                                  "cube0_x": 0.26, "cube0_y": 0.11})
    z0 = -S.SWEEP_CLEARANCE  # the table top in the object frame
    np.testing.assert_allclose(debris.bounds, [[-0.05, 0.0, z0], [-0.03, 0.02, z0 + 0.02]], atol=1e-9)
    with pytest.raises(ValueError, match="cube0_size"):
        S.sweep_object_mesh({"n_cubes": 1, "line_x": 0, "line_y": 0, "cube0_size": -0.01})


@pytest.fixture(scope="module")
def env(make_task_env):
    return make_task_env("sweep")


@pytest.mark.sim
def test_same_seed_same_scene_cubes_start_outside_the_zone(env) -> None:
    from envs.tasks.sweep import CUBE_COUNT_RANGE

    env.reset(seed=5)
    first = dict(env.scene_params)
    env.reset(seed=6)
    other = dict(env.scene_params)
    env.reset(seed=5)
    assert env.scene_params == first and other != first
    for seed in range(8):
        env.reset(seed=seed)
        n = int(env.scene_params["n_cubes"])
        assert CUBE_COUNT_RANGE[0] <= n <= CUBE_COUNT_RANGE[1] and len(env.cubes) == n
        start = env.cube_start_positions()
        np.testing.assert_allclose(env.cube_positions(), start, atol=1e-6)  # as built
        assert not env.cubes_in_zone(start).any()
        lo, _ = env.zone_box()
        assert np.all(start[:, 0] < lo[0])  # behind the zone's near edge, in the sweep's path
    # a second of physics without the hand acting: nothing drifts into the zone, no success
    for _ in range(250):
        env.scene.step()
    info = env.evaluate()
    assert not bool(info["success"][0]) and float(info["cubes_in_zone"][0]) == 0.0
    assert np.max(np.linalg.norm(env.cube_positions() - env.cube_start_positions(), axis=1)) < 2e-3


@pytest.mark.sim
def test_success_is_read_from_the_cube_positions(env) -> None:
    """Cubes pushed (by hand-written test poses) into the zone count; a cube placed there from the start would not."""
    import sapien

    env.reset(seed=2)
    lo, hi = env.zone_box()
    inside = [(lo[0] + 0.03 + 0.025 * i, (lo[1] + hi[1]) / 2) for i in range(4)]
    for cube, (x, y) in zip(env.cubes, inside):
        cube.set_pose(sapien.Pose(p=[x, y, 0.01]))
    for _ in range(10):
        env.scene.step()
    info = env.evaluate()
    assert float(info["cubes_in_zone"][0]) == 4.0 and bool(info["success"][0])  # N = 4 > 3
    env.cubes[3].set_pose(sapien.Pose(p=[lo[0] - 0.05, lo[1] - 0.05, 0.01]))
    env.scene.step()
    info = env.evaluate()
    assert float(info["cubes_in_zone"][0]) == 3.0 and not bool(info["success"][0])  # N = 3 is not > 3
    assert float(info["mean_displacement_cm"][0]) > 5.0


@pytest.mark.sim
def test_expert_sweeps_and_a_wrong_plan_does_not(executor, monkeypatch) -> None:
    from honesty import assert_tool_held_by_contact_only, no_state_writes

    for seed in (11, 12):
        executor.observe(seed=seed)
        with no_state_writes(monkeypatch) as writes:
            result = executor.run(EXPERT)
        assert writes == []
        assert result.success, (seed, result.outcome, result.notes)
        assert result.outcome["cubes_in_zone"] > 3 and result.outcome["mean_displacement_cm"] > 3.0
        assert_tool_held_by_contact_only(executor.env)
    # the same grasp and stance, swept along the arm's Y: the cubes go sideways, not into the zone
    for seed in (11, 12):
        result = executor.run((0, 3, 2, 0, 3, 0), seed=seed)
        assert not result.success and result.outcome["cubes_in_zone"] <= 3, result.outcome


@pytest.mark.sim
def test_open_fingers_never_sweep(executor, monkeypatch) -> None:
    from prl import stages as ex

    wrap = ex.GRASP_POSTURES["medium_wrap"]
    monkeypatch.setitem(ex.GRASP_POSTURES, "medium_wrap", replace(wrap, closed=wrap.open))
    for seed in (11, 12, 13):
        result = executor.run(EXPERT, seed=seed)
        assert not result.success and result.outcome["cubes_in_zone"] == 0, result.outcome
        # the broom never left the table's neighbourhood of its rack: it was not carried
        assert np.max(result.tool_pose[:, 2]) < 0.2


@pytest.mark.sim
def test_bad_input_names_the_bad_value(executor) -> None:
    from envs.tasks import make_env

    with pytest.raises(ValueError, match="unknown task 'swep'"):
        make_env("swep")
    with pytest.raises(ValueError, match="9"):
        executor.run((0, 3, 2, 0, 2, 9), seed=1)
    with pytest.raises(ValueError, match="randomization must be a positive number, got -1"):
        make_env("sweep", randomization=-1)


@pytest.mark.sim
def test_a_hand_pushing_the_cubes_is_not_sweeping() -> None:
    """The hand itself, fingers flat 1.2 cm over the table, driven 25 cm along +X through the debris: five cubes
    end in the zone (until 2026-12-02 a success, N = 5), none of them counts: a hand link pressed on each."""
    import torch

    from envs.tasks import make_env

    gym_env = make_env("sweep", control_mode="pd_joint_pos", obs_mode="none")
    try:
        gym_env.reset(seed=1)
        env = gym_env.unwrapped
        robot, p = env.agent.robot, env.scene_params
        target = robot.get_qpos()[0].numpy().astype(np.float64)  # ARTx, ARTy, ARTz: world-aligned base slides
        links = {link.name: link.pose.p[0].numpy() for link in robot.get_links()}
        target[0] += (p["line_x"] - 0.12) - links["ff_distal"][0]  # the fingertips behind the debris
        target[1] += p["line_y"] - links["palm"][1]

        def hold(steps: int) -> None:
            for _ in range(steps):
                gym_env.step(torch.as_tensor(target, dtype=torch.float32)[None])

        hold(40)
        target[2] += 0.012 - links["ff_distal"][2]
        hold(40)
        for _ in range(50):
            target[0] += 0.005
            hold(1)
        hold(20)
        info = env.evaluate()
        assert float(info["zone_cubes_hand_touched"][0]) >= 4
        assert float(info["cubes_in_zone"][0]) == 0 and not bool(info["success"][0])
    finally:
        gym_env.close()


@pytest.mark.sim
def test_a_loose_broom_knocked_into_the_cubes_is_not_sweeping() -> None:
    """No hand holds the broom: flung head first at 2 m/s along the table into the debris, it pushes a cube into the
    zone; that cube does not count (the broom pressed on it with no hand link on the broom)."""
    import sapien
    import torch

    from envs.tasks import make_env

    gym_env = make_env("sweep", robot_uids="none", obs_mode="none")
    try:
        env = gym_env.unwrapped
        env.reset(seed=2)
        p = env.scene_params
        env.tool.set_pose(sapien.Pose(p=[p["line_x"] - 0.12, p["line_y"], 0.03], q=[0, 0, 0, 1]))  # head first
        env.tool.set_linear_velocity(torch.tensor([[2.0, 0.0, 0.0]]))
        for _ in range(500):
            env.step_physics()
        info = env.evaluate()
        assert float(info["zone_cubes_loose_pushed"][0]) >= 1
        assert float(info["cubes_in_zone"][0]) == 0 and not bool(info["success"][0])
    finally:
        gym_env.close()
