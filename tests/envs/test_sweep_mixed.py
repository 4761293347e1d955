"""PRL-SweepMixed-v1 (issue #26): each scene's family is drawn from its seed, each family needs its own plan (its
expert sweeps its debris into the zone, the other family's does not), x tells the families apart, the base task's
honesty rules hold on both families, and a bad family table is an error naming the bad value."""

from __future__ import annotations

import numpy as np
import pytest

SWEEP_SEEDS = {0: 0, 1: 1}
"""A scene of each sweep_mixed family (seed 0: along X, seed 1: across, along Y; checked below)."""


@pytest.fixture(scope="module")
def env(make_task_env):
    return make_task_env("sweep_mixed")


def _cls():
    from envs.tasks.sweep_mixed import PRLSweepMixedEnv  # heavy: loads the simulator's modules (no scene)

    return PRLSweepMixedEnv


def _yaw(pose7: np.ndarray) -> float:
    """Yaw (rad) of a [x, y, z, qw, qx, qy, qz] pose whose rotation is about Z (or nearly)."""
    return float(2.0 * np.arctan2(pose7[6], pose7[3]))


def _angle(a: float) -> float:
    """``a`` wrapped into (-pi, pi]."""
    return float(np.angle(np.exp(1j * a)))


# ------------------------------------------------------------------ pure logic (no scene is built)
def test_a_malformed_sweep_family_is_named() -> None:
    from envs.tasks.sweep_mixed import SweepFamily

    with pytest.raises(ValueError, match=r"sweep family 'odd': turn_deg must be one of \(0, 90, 180, 270\), got 45"):
        SweepFamily("odd", turn_deg=45, rack_xy=(0.0, 0.0), line_xy=(0.0, 0.1))
    with pytest.raises(ValueError, match=r"sweep family 'odd': turn_deg must be one of .* got True"):
        SweepFamily("odd", turn_deg=True, rack_xy=(0.0, 0.0), line_xy=(0.0, 0.1))
    with pytest.raises(ValueError, match=r"sweep family 'odd': line_xy must be a point \(x, y\), got \(0.0,\)"):
        SweepFamily("odd", turn_deg=0, rack_xy=(0.0, 0.0), line_xy=(0.0,))
    with pytest.raises(ValueError, match=r"sweep family 'odd': cube_mass must be a range .* got \(0.02, 0.01\)"):
        SweepFamily("odd", turn_deg=0, rack_xy=(0.0, 0.0), line_xy=(0.0, 0.1), cube_mass=(0.02, 0.01))


# ------------------------------------------------------------------ physics
@pytest.mark.sim
def test_the_family_is_drawn_from_the_seed(env) -> None:
    from envs.tasks.sweep import BROOM_REST_YAW_RANGE, PRLSweepEnv

    seen = {}
    for seed in range(8):
        env.reset(seed=seed)
        family = env.scene_params["family"]
        assert type(family) is int and family in (0, 1)
        seen[seed] = (family, dict(env.scene_params), env.zone_box())
    assert {f for f, _, _ in seen.values()} == {0, 1}  # both families among 8 seeds
    assert {s: f for s, (f, _, _) in seen.items() if s in SWEEP_SEEDS} == SWEEP_SEEDS
    for seed in (3, 0, 3):  # the same seed again, after other scenes: the same family and the same scene
        env.reset(seed=seed)
        assert env.scene_params == seen[seed][1]
    for seed, (family, p, (lo, hi)) in seen.items():
        spec = _cls().families[family]
        turn = np.deg2rad(spec.turn_deg)
        assert p["sweep_yaw"] == turn and abs(_angle(p["rack_yaw"] - turn)) <= BROOM_REST_YAW_RANGE + 1e-9
        assert np.hypot(p["line_x"] - spec.line_xy[0], p["line_y"] - spec.line_xy[1]) <= 0.02 * np.sqrt(2) + 1e-9
        # the debris lie behind the sweep line along the sweep frame's X, across its Y
        along = np.array([np.cos(turn), np.sin(turn)])
        across = np.array([-np.sin(turn), np.cos(turn)])
        for i in range(int(p["n_cubes"])):
            d = np.array([p[f"cube{i}_x"] - p["line_x"], p[f"cube{i}_y"] - p["line_y"]])
            assert -0.073 < d @ along < -0.037 and abs(d @ across) < 0.048, (seed, i, d)
        # the zone: 16 cm deep along the sweep frame's X from 0-1 cm past the line, 18 cm wide
        assert np.allclose(np.abs(along) @ (hi - lo), 0.16) and np.allclose(np.abs(across) @ (hi - lo), 0.18)
        if family == 1:  # the zone beyond the line along +Y, centred on it along X
            assert p["line_y"] <= lo[1] <= p["line_y"] + 0.01 and np.isclose(lo[0] + hi[0], 2 * p["line_x"])
    env.reset(seed=0)  # family 0: the base task's zone, from the same values
    base_lo, base_hi = PRLSweepEnv.zone_box(env)
    np.testing.assert_allclose(env.zone_box()[0], base_lo, atol=1e-12)
    np.testing.assert_allclose(env.zone_box()[1], base_hi, atol=1e-12)
    assert not env.cubes_in_zone(env.cube_start_positions()).any()  # every cube starts outside the zone


@pytest.mark.sim
def test_each_family_needs_its_own_plan(env, executor, monkeypatch) -> None:
    """On a scene of each family its expert sweeps more than 3 cubes into the zone and the other family's expert
    sweeps none (measured on 30 scenes of each family: own expert 30/30 and 30/30, the other's 0/30 and 0/30)."""
    from honesty import no_state_writes

    plans = _cls().family_expert_plans
    for family, seed in SWEEP_SEEDS.items():
        executor.observe(seed=seed)
        assert env.scene_params["family"] == family
        with no_state_writes(monkeypatch) as writes:
            own = executor.run(plans[family])
        assert writes == []
        assert own.success and own.outcome["cubes_in_zone"] > 3, (family, own.outcome)
        assert own.outcome["zone_cubes_hand_touched"] == 0 and own.outcome["zone_cubes_loose_pushed"] == 0
        other = executor.run(plans[1 - family], seed=seed)
        assert not other.success and other.outcome["cubes_in_zone"] == 0, (family, other.outcome)


@pytest.mark.sim
def test_x_tells_the_families_apart(env, executor, pointnet_path) -> None:
    """The debris patch rebuilt from scene_params (the base task's builders) lies across X in one family and across
    Y in the other, so its point cloud and PointNet feature differ; x_manip records the sweep frame's and the broom's
    yaw, a quarter turn apart. The family index is read by no mesh builder (x does not contain it)."""
    import prl.shapes as S
    from prl.demo import X_MANIP_LAYOUT, X_MANIP_SAMPLES
    from prl.features import point_features
    from prl.pointnet import load_pointnet

    params, x_manip = {}, {}
    for family, seed in SWEEP_SEEDS.items():
        x_manip[family] = executor.observe(seed=seed)
        params[family] = dict(env.scene_params)
    extents = {f: [m.extents for m in S.scene_meshes("sweep_mixed", p)] for f, p in params.items()}
    assert extents[0][1][1] > extents[0][1][0] + 0.03  # the patch: long across X (family 0) ...
    assert extents[1][1][0] > extents[1][1][1] + 0.03  # ... long across Y (family 1)
    for p in params.values():  # the variant's meshes are the base task's, from the same values, without the family
        without = {k: v for k, v in p.items() if k != "family"}
        for mine, base in zip(S.scene_meshes("sweep_mixed", p), S.scene_meshes("sweep", without), strict=True):
            np.testing.assert_allclose(mine.vertices, base.vertices)
    # x_manip: the object (sweep frame) pose and the broom's pose, per observation sample
    width = sum(w for _, w in X_MANIP_LAYOUT)
    start = {}
    offset = 0
    for name, w in X_MANIP_LAYOUT:
        start[name] = offset
        offset += w
    samples = {f: x.reshape(X_MANIP_SAMPLES, width) for f, x in x_manip.items()}
    obj_yaw = {f: _yaw(s[-1, start["object_pose"]:start["object_pose"] + 7]) for f, s in samples.items()}
    tool_yaw = {f: _yaw(s[-1, start["tool_pose"]:start["tool_pose"] + 7]) for f, s in samples.items()}
    assert abs(obj_yaw[0]) < 1e-3 and abs(obj_yaw[1] - np.pi / 2) < 1e-3, obj_yaw
    assert abs(abs(_angle(tool_yaw[1] - tool_yaw[0])) - np.pi / 2) < np.deg2rad(17), tool_yaw  # 90 deg +- 2 x 8 deg
    assert x_manip[0].shape == x_manip[1].shape and np.isfinite(x_manip[0]).all() and np.isfinite(x_manip[1]).all()
    pointnet = load_pointnet(pointnet_path)
    _, obj = point_features(pointnet, ["sweep_mixed"] * 2, list(SWEEP_SEEDS.values()), [params[0], params[1]], 64)
    assert not np.allclose(obj[0], obj[1])


@pytest.mark.sim
def test_open_fingers_and_cubes_that_cannot_move_fail_on_both_families(env, executor,
                                                                       monkeypatch) -> None:
    """The base task's honesty rules hold on the variant: each family's expert with its grasp's closed posture
    replaced by the open one (limp fingers) sweeps no cube, nor does it on cubes of a tonne each (an immovable
    object, from a patched family table); nothing is written to a pose while the plan runs."""
    from dataclasses import replace

    from honesty import no_state_writes

    from prl import stages as ex
    from prl.plb import load_plb

    cls = _cls()
    names = next(d.choices for d in load_plb().dims if d.name == "grasp_pattern")
    for family, seed in SWEEP_SEEDS.items():
        plan = cls.family_expert_plans[family]
        posture = names[plan[3]]
        with monkeypatch.context() as m:
            closed = ex.GRASP_POSTURES[posture]
            m.setitem(ex.GRASP_POSTURES, posture, replace(closed, closed=closed.open))
            executor.observe(seed=seed)
            with no_state_writes(m) as writes:
                limp = executor.run(plan)
            assert writes == []
        assert env.scene_params["family"] == family
        assert not limp.success and limp.outcome["cubes_in_zone"] == 0, (family, limp.outcome)
    heavy = tuple(replace(spec, cube_mass=(1000.0, 1000.0)) for spec in cls.families)
    monkeypatch.setattr(cls, "families", heavy)
    for family, seed in SWEEP_SEEDS.items():
        executor.observe(seed=seed)
        with no_state_writes(monkeypatch) as writes:
            result = executor.run(cls.family_expert_plans[family])
        assert writes == []
        assert env.scene_params["family"] == family
        assert env.scene_params["cube0_mass"] == 1000.0  # the scene was rebuilt from the patched table
        assert not result.success and result.outcome["cubes_in_zone"] == 0, (family, result.outcome)
        assert result.outcome["mean_displacement_cm"] < 0.5, (family, result.outcome)
