"""PRL-HammerMixed-v1 (issue #26): each scene's family is drawn from its seed (an upright nail in a board, or one
leaning towards the hammer out of a slanted block), each family needs its own plan (its expert drives its nail, the
other family's does not), x tells the families apart (the nail's pose in x_manip), the base task's honesty rules
hold, and a bad family table is an error naming the bad value."""

from __future__ import annotations

import numpy as np
import pytest

HAMMER_SEEDS = {0: 0, 1: 1}
"""A scene of each hammer_mixed family (seed 0: an upright nail, seed 1: a slanted one; checked below)."""


@pytest.fixture(scope="module")
def env(make_task_env):
    return make_task_env("hammer_mixed")


def _cls():
    from envs.tasks.hammer_mixed import PRLHammerMixedEnv  # heavy: loads the simulator's modules (no scene)

    return PRLHammerMixedEnv


def _object_z(x_manip: np.ndarray) -> np.ndarray:
    """(8, 3) the object frame's Z axis in each observation sample of x_manip (its last 7 values per sample)."""
    import sapien

    from prl.demo import X_MANIP_LAYOUT, X_MANIP_SAMPLES

    width = sum(w for _, w in X_MANIP_LAYOUT)
    poses = np.asarray(x_manip, dtype=np.float64).reshape(X_MANIP_SAMPLES, width)[:, -7:]
    return np.stack([sapien.Pose(p=p[:3], q=p[3:]).to_transformation_matrix()[:3, 2] for p in poses])


# ------------------------------------------------------------------ pure logic (no scene is built)
def test_a_malformed_nail_family_is_named() -> None:
    from envs.tasks.hammer_mixed import NailFamily

    with pytest.raises(ValueError, match=r"nail family 'odd': tilt_deg must be a range .* got \(45.0, 35.0\)"):
        NailFamily("odd", tilt_deg=(45.0, 35.0))
    with pytest.raises(ValueError, match=r"nail family 'odd': tilt_deg must be a range .* got \(80.0, 95.0\)"):
        NailFamily("odd", tilt_deg=(80.0, 95.0))
    with pytest.raises(ValueError, match=r"nail family 'odd': nail_hold_force must be a range .* got \(0.0, 5.0\)"):
        NailFamily("odd", tilt_deg=(0.0, 0.0), nail_hold_force=(0.0, 5.0))
    with pytest.raises(ValueError, match=r"nail family 'odd': block_half_size must be three positive .* got \(0.08, 0.08\)"):
        NailFamily("odd", tilt_deg=(0.0, 0.0), block_half_size=(0.08, 0.08))


# ------------------------------------------------------------------ physics
@pytest.mark.sim
def test_the_family_is_drawn_from_the_seed(env) -> None:
    from envs.tasks.hammer_mixed import SLANTED, UPRIGHT

    seen = {}
    for seed in range(8):
        env.reset(seed=seed)
        family = env.scene_params["family"]
        assert type(family) is int and family in (0, 1)
        seen[seed] = (family, dict(env.scene_params))
    assert {f for f, _ in seen.values()} == {0, 1}  # both families among 8 seeds
    assert {s: f for s, (f, _) in seen.items() if s in HAMMER_SEEDS.values()} == {s: f for f, s in HAMMER_SEEDS.items()}
    for seed in (3, 0, 3):  # the same seed again, after other scenes: the same family and the same scene
        env.reset(seed=seed)
        assert env.scene_params == seen[seed][1]
    for family, params in seen.values():  # each family's values lie in its own ranges
        spec = (UPRIGHT, SLANTED)[family]
        assert spec.tilt_deg[0] - 1e-9 <= np.rad2deg(params["nail_tilt"]) <= spec.tilt_deg[1] + 1e-9
        assert spec.nail_hold_force[0] <= params["nail_hold_force"] <= spec.nail_hold_force[1]


@pytest.mark.sim
def test_each_family_needs_its_own_plan(env, executor, monkeypatch) -> None:
    """On a scene of each family its expert drives the nail more than 1 cm and the other family's expert does not
    (measured: family 0 on seeds 20000-20119 own expert 57/57, the other's 0/57; family 1 at 55-65 deg on seeds
    40000-40059 own expert 60/60, the other's 0/60)."""
    from honesty import no_state_writes

    plans = _cls().family_expert_plans
    for family, seed in HAMMER_SEEDS.items():
        executor.observe(seed=seed)
        assert env.scene_params["family"] == family
        with no_state_writes(monkeypatch) as writes:
            own = executor.run(plans[family])
        assert writes == []
        assert own.success and own.outcome["nail_descent_cm"] > 1.0, (family, own.outcome)
        other = executor.run(plans[1 - family], seed=seed)
        assert not other.success, (family, other.outcome)


@pytest.mark.sim
def test_the_searchs_best_fixed_plan_drives_only_upright_nails(env, executor) -> None:
    """The best fixed plan of the variant search (``docs/variant_search.md``: a precision disk lifting the hammer
    along Z, ``[1,3,1,3,4,0]``) drove all 25 upright nails of its check scenes and 4 of the 25 slanted ones: here it
    drives the upright nail of seed 0 and leaves two slanted nails of its check scenes (seeds 3231808077 and
    1504193527, where it failed) short of 1 cm, while their family's expert drives them."""
    best, plans = (1, 3, 1, 3, 4, 0), _cls().family_expert_plans
    assert executor.run(best, seed=HAMMER_SEEDS[0]).success
    for seed in (3231808077, 1504193527):
        executor.observe(seed=seed)
        assert env.scene_params["family"] == 1
        missed = executor.run(best)
        assert not missed.success and missed.outcome["nail_descent_cm"] <= 1.0, missed.outcome
        assert executor.run(plans[1], seed=seed).success


@pytest.mark.sim
def test_success_is_a_descent_above_one_centimetre(env, executor) -> None:
    """The variant counts d > 1 cm (the paper's stricter level), the base task d > 0.05 cm: the same measured
    descent, set on the env's record of what the held hammer drove, is judged by both rules."""
    from envs.tasks.hammer import PRLHammerEnv

    executor.observe(seed=HAMMER_SEEDS[0])
    for drive_m, variant, base_rule in ((0.0004, False, False), (0.006, False, True), (0.011, True, True)):
        env._hammer_drive = drive_m
        info = env.evaluate()
        assert bool(info["success"]) is variant and abs(float(info["nail_descent_cm"]) - 100 * drive_m) < 1e-6
        assert bool(PRLHammerEnv.evaluate(env)["success"]) is base_rule


@pytest.mark.sim
def test_x_tells_the_families_apart(env, executor, pointnet_path) -> None:
    """x_manip records the nail's frame in the observation phase: its Z axis is vertical in family 0 and leans
    within family 1's range (55-65 deg) towards the board's -X in family 1. The meshes rebuilt from scene_params are the base task's from the
    same values, with or without the family index (the index is in no part of x)."""
    import prl.shapes as S
    from prl.features import point_features
    from prl.pointnet import load_pointnet

    params, x_manip = {}, {}
    for family, seed in HAMMER_SEEDS.items():
        x_manip[family] = executor.observe(seed=seed)
        params[family] = dict(env.scene_params)
    assert x_manip[0].shape == x_manip[1].shape and np.isfinite(x_manip[0]).all() and np.isfinite(x_manip[1]).all()
    z = {f: _object_z(x) for f, x in x_manip.items()}
    lean = {f: np.rad2deg(np.arccos(np.clip(v[:, 2], -1.0, 1.0))) for f, v in z.items()}
    assert np.all(lean[0] < 1.0), lean[0]  # upright
    low, high = _cls().families[1].tilt_deg
    assert np.all((lean[1] > low - 1.0) & (lean[1] < high + 1.0)), lean[1]  # leaning
    yaw = params[1]["board_yaw"]
    towards = z[1][:, :2] @ np.array([np.cos(yaw), np.sin(yaw)])  # along the board's X: negative (towards -X)
    assert np.all(towards < -0.5), towards
    for p in params.values():  # the variant's meshes are the base task's, from the same values, family or not
        without = {k: v for k, v in p.items() if k != "family"}
        for mine, base in zip(S.scene_meshes("hammer_mixed", p), S.scene_meshes("hammer", without), strict=True):
            np.testing.assert_allclose(mine.vertices, base.vertices)
    pointnet = load_pointnet(pointnet_path)
    tool, obj = point_features(pointnet, ["hammer_mixed"] * 2, list(HAMMER_SEEDS.values()), [params[0], params[1]],
                               64)
    assert np.isfinite(tool).all() and np.isfinite(obj).all()


@pytest.mark.sim
def test_limp_fingers_and_a_nail_that_cannot_move_fail_on_both_families(env, executor,
                                                                        monkeypatch) -> None:
    """The base task's honesty rules hold on the variant: each family's expert with its grasp's closed posture
    replaced by the open one (limp fingers) does not drive the nail, nor does it drive a nail held by 1e5 N (an
    immovable object, from a patched family table); nothing is written to a pose while the plan runs."""
    from dataclasses import replace

    from honesty import no_state_writes

    from prl import stages as ex
    from prl.plb import load_plb

    cls = _cls()
    names = next(d.choices for d in load_plb().dims if d.name == "grasp_pattern")
    for family, seed in HAMMER_SEEDS.items():
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
        assert not limp.success and limp.outcome["nail_descent_cm"] <= 0.05, (family, limp.outcome)
    stuck = tuple(replace(spec, nail_hold_force=(1e5, 1e5)) for spec in cls.families)
    monkeypatch.setattr(cls, "families", stuck)
    for family, seed in HAMMER_SEEDS.items():
        executor.observe(seed=seed)
        with no_state_writes(monkeypatch) as writes:
            result = executor.run(cls.family_expert_plans[family])
        assert writes == []
        assert env.scene_params["family"] == family
        assert env.scene_params["nail_hold_force"] == 1e5  # the scene was rebuilt from the patched table
        assert not result.success and result.outcome["nail_depth_cm"] < 0.05, (family, result.outcome)
