"""PRL-TweezeMixed-v1 (issue #26): each scene's family is drawn from its seed, each family needs its own plan (its
expert lifts the object on its scenes, the other family's does not, nor do the plans that once solved both), x tells
the families apart, the base task's honesty rules hold, and a bad family table is an error naming the bad value."""

from __future__ import annotations

import numpy as np
import pytest

TWEEZE_SEEDS = {0: 0, 1: 1}
"""A scene of each tweeze_mixed family (seed 0: the base task's tweezers and a flat tile, seed 1: long tweezers with a
tall block standing deep between the arms; checked below)."""

OLD_WINNERS = ((0, 2, 4, 3, 1, 1), (3, 0, 4, 2, 6, 1))
"""The best fixed plans of the search on the variant before the tall block (46/50 and 32/50 of its check scenes):
the untilted precision disk and the palmar pinch at anchor 4, the hand's little-finger side over the deep
object."""
TALL_SEED = 5
"""A family 1 scene on which both ``OLD_WINNERS`` touch the tall block."""
WRAP = (3, 3, 1, 0, 4, 1)
"""The search's best fixed plan on the variant with the block 5.0-5.7 cm deep (43/50 of the check scenes): a medium
wrap at anchor 1, lifted by the arm."""


@pytest.fixture(scope="module")
def env(make_task_env):
    return make_task_env("tweeze_mixed")


def _cls():
    from envs.tasks.tweeze_mixed import PRLTweezeMixedEnv  # heavy: loads the simulator's modules (no scene)

    return PRLTweezeMixedEnv


# ------------------------------------------------------------------ pure logic (no scene is built)
def test_a_malformed_tweeze_family_is_named() -> None:
    from envs.tasks.tweeze_mixed import TweezeFamily

    with pytest.raises(ValueError, match=r"tweeze family 'odd': arm_length must be a range .*0 < low <= high.* "
                                         r"got \(0.2, 0.1\)"):
        TweezeFamily("odd", arm_length=(0.2, 0.1))
    with pytest.raises(ValueError, match=r"tweeze family 'odd': cube_size must be a range .* got \(0.0, 0.02\)"):
        TweezeFamily("odd", cube_size=(0.0, 0.02))
    with pytest.raises(ValueError, match=r"tweeze family 'odd': cube_along must be a range .*low <= high.* "
                                         r"got \(-0.05, -0.06\)"):
        TweezeFamily("odd", cube_along=(-0.05, -0.06))
    with pytest.raises(ValueError, match=r"tweeze family 'odd': tip_gap must be a range .* got \(0.04,\)"):
        TweezeFamily("odd", tip_gap=(0.04,))
    with pytest.raises(ValueError, match=r"tweeze family 'odd': height_ratio must be a range .* got \(0.0, 2.0\)"):
        TweezeFamily("odd", height_ratio=(0.0, 2.0))
    TweezeFamily("deep", cube_along=(-0.07, -0.06))  # negative positions along the arms are fine


# ------------------------------------------------------------------ physics
@pytest.mark.sim
def test_the_family_is_drawn_from_the_seed(env) -> None:
    from envs.tasks.tweeze_mixed import TALL_DEEP, TIPS

    seen = {}
    for seed in range(8):
        env.reset(seed=seed)
        family = env.scene_params["family"]
        assert type(family) is int and family in (0, 1)
        seen[seed] = (family, dict(env.scene_params))
    assert {f for f, _ in seen.values()} == {0, 1}  # both families among 8 seeds
    assert {s: f for s, (f, _) in seen.items() if s in TWEEZE_SEEDS} == TWEEZE_SEEDS
    for seed in (3, 0, 3):  # the same seed again, after other scenes: the same family and the same scene
        env.reset(seed=seed)
        assert env.scene_params == seen[seed][1]
    for family, params in seen.values():  # each family's values lie in its own ranges
        spec = (TIPS, TALL_DEEP)[family]
        for key in ("arm_length", "tip_gap", "cube_size", "cube_along"):
            low, high = getattr(spec, key)
            assert low <= params[key] <= high, (family, key, params[key])
        low, high = spec.height_ratio
        assert low - 1e-9 <= params["cube_height"] / params["cube_size"] <= high + 1e-9, (family, params)


@pytest.mark.sim
def test_each_family_needs_its_own_plan(env, executor, monkeypatch) -> None:
    """On a scene of each family its expert lifts the object with the tips (no hand link ever touching it) and the
    other family's expert does not (measured on the search's 50 balanced check scenes: own expert 24/25 and 24/25,
    crossed 0/25 and 0/25: on family 0 the hand at anchor 5 squeezes too near the hinge, on family 1 the pinch at
    anchor 4 touches the tall block). Nothing is written to a pose while the plan runs."""
    from honesty import no_state_writes

    plans = _cls().family_expert_plans
    for family, seed in TWEEZE_SEEDS.items():
        executor.observe(seed=seed)
        assert env.scene_params["family"] == family
        with no_state_writes(monkeypatch) as writes:
            own = executor.run(plans[family])
        assert writes == []
        assert own.success and own.outcome["cube_lift_cm"] > 10.0, (family, own.outcome)
        assert not own.outcome["hand_touches_cube"], (family, own.outcome)
        other = executor.run(plans[1 - family], seed=seed)
        assert not other.success, (family, other.outcome)


@pytest.mark.sim
def test_the_untilted_pinch_lifts_the_tile_but_touches_the_base_tasks_cube(env, executor, monkeypatch) -> None:
    """Why family 0 holds a flat tile (the module's docstring): the untilted pinch at anchor 4 (family 0's plan, and
    the mode of the prior's successes on the tile) lifts the tile by the tips with no hand link on it; on the same
    scene with the base task's cube (height ratio 1, a patched family table) it lifts the cube with a hand link
    pressing on it, which never counts (0/12 cubes on scenes 54000-54011, ``envs.family_probe``). Nothing is
    written to a pose while the plan runs."""
    from dataclasses import replace

    from honesty import no_state_writes

    cls = _cls()
    plan = cls.family_expert_plans[0]
    assert plan[:4] == (0, 3, 4, 2)  # untilted about X and Z, anchor 4, palmar pinch
    executor.observe(seed=TWEEZE_SEEDS[0])
    assert env.scene_params["cube_height"] < 0.5 * env.scene_params["cube_size"]
    with no_state_writes(monkeypatch) as writes:
        tile = executor.run(plan)
    assert writes == []
    assert tile.success and not tile.outcome["hand_touches_cube"], tile.outcome
    monkeypatch.setattr(cls, "families", tuple(replace(spec, height_ratio=(1.0, 1.0)) for spec in cls.families))
    executor.observe(seed=TWEEZE_SEEDS[0])
    assert env.scene_params["family"] == 0 and env.scene_params["cube_height"] == env.scene_params["cube_size"]
    cube = executor.run(plan)
    assert not cube.success and cube.outcome["hand_touches_cube"] and cube.outcome["cube_lift_cm"] > 10.0, cube.outcome


@pytest.mark.sim
def test_the_plans_that_solved_both_families_touch_the_tall_block(env, executor) -> None:
    """The best fixed plans of the variant before its family 1 held a tall block (``OLD_WINNERS``): on family 1's
    scene a hand link presses on the tall block (not a success). The untilted disk still lifts family 0's tile by
    the tips (20/20 on scenes 58000-58019, ``envs.family_probe``), so it is the tall block that refuses it."""
    for plan in OLD_WINNERS:
        executor.observe(seed=TALL_SEED)
        assert env.scene_params["family"] == 1
        tall = executor.run(plan)
        assert not tall.success and tall.outcome["hand_touches_cube"], (plan, tall.outcome)
    executor.observe(seed=TWEEZE_SEEDS[0])
    assert env.scene_params["family"] == 0
    tile = executor.run(OLD_WINNERS[0])
    assert tile.success and not tile.outcome["hand_touches_cube"], tile.outcome


FAMILY_1_SEEDS = (1, 5, 7, 8, 10, 11)
"""The first six family 1 scenes (tall blocks standing deep between the arms)."""


@pytest.mark.sim
def test_the_wrap_lifts_the_tile_and_fewer_deep_blocks_than_with_a_shorter_stand(env, executor,
                                                                                   monkeypatch) -> None:
    """The wrap that solved both families while the block stood 5.0-5.7 cm deep (``WRAP``) lifts family 0's tile,
    and at most half of family 1's blocks, now 6.5-7.1 cm deep (5/25 on the search's check scenes). With the stand
    under the block and the arms 1.2 cm shorter (``CUBE_REST_MARGIN`` patched from 4 mm behind the block to 8 mm
    under it) the same wrap lifts more of the same blocks: the stand under the arms is part of what stops it (the
    module's docstring). Counted over six scenes, not read from one: which blocks lift is chaotic, and PhysX on two
    machines has given scene 1 a lifted and an unlifted block (here: 2 of 6 lifted, 5 of 6 with the shorter stand).
    Lifted: higher than the base task's success lift (10 cm), whether or not a hand link touched it."""
    import envs.tasks.tweeze_mixed as module
    from envs.tasks.tweeze import SUCCESS_LIFT_CM

    executor.observe(seed=TWEEZE_SEEDS[0])
    assert env.scene_params["family"] == 0
    tile = executor.run(WRAP)
    assert tile.success and not tile.outcome["hand_touches_cube"], tile.outcome

    def lifted() -> list[bool]:
        out = []
        for seed in FAMILY_1_SEEDS:
            executor.observe(seed=seed)
            assert env.scene_params["family"] == 1
            out.append(float(executor.run(WRAP).outcome["cube_lift_cm"]) > SUCCESS_LIFT_CM)
        return out

    deep = lifted()
    monkeypatch.setattr(module, "CUBE_REST_MARGIN", -0.008)
    shorter = lifted()
    assert sum(deep) <= len(FAMILY_1_SEEDS) / 2 < sum(shorter), (deep, shorter)


@pytest.mark.sim
def test_x_tells_the_families_apart(env, executor, pointnet_path) -> None:
    """The meshes rebuilt from scene_params (the class's builders: the base task's tweezers, the variant's block)
    differ between the families (the tweezers' length in the tool cloud; the object's edge and, above all, its
    height in the object's: a flat tile, or a block 2.6-3 times as tall as wide), as do their PointNet features;
    and x_manip's recorded poses place the object much deeper between the arms in family 1 (the family index is in
    no part of x)."""
    import prl.shapes as S
    from prl.demo import X_MANIP_LAYOUT, X_MANIP_SAMPLES
    from prl.features import point_features
    from prl.pointnet import load_pointnet

    params, x_manip = {}, {}
    for family, seed in TWEEZE_SEEDS.items():
        x_manip[family] = executor.observe(seed=seed)
        params[family] = dict(env.scene_params)
    extents = {f: [m.extents for m in S.scene_meshes("tweeze_mixed", p)] for f, p in params.items()}
    assert extents[0][0][0] < 0.19 and extents[1][0][0] > 0.25  # the tweezers' length (arms + butt)
    assert extents[0][1][0] < 0.0251 and extents[1][1][0] > 0.0239  # the object's edge (2.0-2.5 cm, 2.4-2.7 cm)
    np.testing.assert_allclose(extents[0][1][:2], [params[0]["cube_size"]] * 2)  # family 0: a square tile ...
    assert extents[0][1][2] <= 0.45 * extents[0][1][0] + 1e-9 and extents[0][1][2] < 0.0113  # ... at most 1.1 cm thick
    assert extents[1][1][2] >= 2.6 * extents[1][1][0] - 1e-9 and extents[1][1][2] > 0.062  # family 1: a tall block
    for f, p in params.items():  # the tweezers are the base task's, from the same values
        np.testing.assert_allclose(extents[f][0], S.scene_meshes("tweeze", p)[0].extents)

    # x_manip: the cube's distance from the tweezers' hinge (the tool pose's origin), as a fraction of the
    # tweezers' length (which the tool cloud carries)
    width = sum(w for _, w in X_MANIP_LAYOUT)
    start = {name: sum(w for _, w in X_MANIP_LAYOUT[:i]) for i, (name, _) in enumerate(X_MANIP_LAYOUT)}
    depth = {}
    for f, x in x_manip.items():
        assert x.shape == (X_MANIP_SAMPLES * width,) and np.isfinite(x).all()
        first = x.reshape(X_MANIP_SAMPLES, width)[0]
        tool = first[start["tool_pose"]:start["tool_pose"] + 3]
        cube = first[start["object_pose"]:start["object_pose"] + 3]
        depth[f] = float(np.linalg.norm((cube - tool)[:2])) / extents[f][0][0]
    assert depth[0] > 0.8 and depth[1] < 0.72, depth  # near the tips, or deep between the arms

    pointnet = load_pointnet(pointnet_path)
    tool, obj = point_features(pointnet, ["tweeze_mixed"] * 2, list(TWEEZE_SEEDS.values()),
                               [params[0], params[1]], 64)
    assert not np.allclose(tool[0], tool[1]) and not np.allclose(obj[0], obj[1])


@pytest.mark.sim
def test_open_fingers_and_a_cube_that_cannot_be_lifted_fail_on_both_families(env, executor,
                                                                            monkeypatch) -> None:
    """The base task's honesty rules hold on the variant: each family's expert with its grasp's closed posture
    replaced by the open one (limp fingers) does not lift the cube, nor does it lift a 2 kg cube (an object the
    tips' friction cannot carry: a patched family table); nothing is written to a pose while the plan runs."""
    from dataclasses import replace

    from honesty import no_state_writes

    from prl import stages as ex
    from prl.plb import load_plb

    cls = _cls()
    names = next(d.choices for d in load_plb().dims if d.name == "grasp_pattern")
    for family, seed in TWEEZE_SEEDS.items():
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
        assert not limp.success and limp.outcome["cube_lift_cm"] < 10.0, (family, limp.outcome)
    heavy = tuple(replace(spec, cube_mass=(2.0, 2.0)) for spec in cls.families)
    monkeypatch.setattr(cls, "families", heavy)
    for family, seed in TWEEZE_SEEDS.items():
        executor.observe(seed=seed)
        with no_state_writes(monkeypatch) as writes:
            result = executor.run(cls.family_expert_plans[family])
        assert writes == []
        assert env.scene_params["family"] == family
        assert env.scene_params["cube_mass"] == 2.0  # the scene was rebuilt from the patched table
        assert not result.success and result.outcome["cube_lift_cm"] < 10.0, (family, result.outcome)
