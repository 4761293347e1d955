"""The mixed task variants (issue #26): each scene's family is drawn from its seed, each family needs its own plan
(its expert opens its scenes, the other family's does not), x tells the families apart, and a bad family table is
an error naming the bad value."""

from __future__ import annotations

import numpy as np
import pytest

UNSCREW_SEEDS = {0: 0, 1: 1}
"""A scene of each unscrew_mixed family (seed 0: a flask, seed 1: a wide lid; checked below)."""


@pytest.fixture(scope="module")
def env(make_task_env):
    return make_task_env("unscrew_mixed")


def _cls():
    from envs.tasks.unscrew_mixed import PRLUnscrewMixedEnv  # heavy: loads the simulator's modules (no scene)

    return PRLUnscrewMixedEnv


# ------------------------------------------------------------------ pure logic (no scene is built)
def test_a_malformed_cap_family_is_named() -> None:
    from envs.tasks.unscrew_mixed import CapFamily

    with pytest.raises(ValueError, match=r"cap family 'odd': cap_radius must be a range .* got \(0.03, 0.01\)"):
        CapFamily("odd", cap_radius=(0.03, 0.01), breakaway_torque=(1.0, 2.0), body_radius=(0.02, 0.03),
                  shoulder_gap=(0.003, 0.006))
    with pytest.raises(ValueError, match="cap family 'odd': give exactly one of body_height and shoulder_gap"):
        CapFamily("odd", cap_radius=(0.01, 0.02), breakaway_torque=(1.0, 2.0), body_radius=(0.02, 0.03))


# ------------------------------------------------------------------ physics
@pytest.mark.sim
def test_the_family_is_drawn_from_the_seed(env) -> None:
    seen = {}
    for seed in range(8):
        env.reset(seed=seed)
        family = env.scene_params["family"]
        assert type(family) is int and family in (0, 1)
        seen[seed] = (family, dict(env.scene_params))
    assert {f for f, _ in seen.values()} == {0, 1}  # both families among 8 seeds
    assert {s: f for s, (f, _) in seen.items() if s in UNSCREW_SEEDS} == UNSCREW_SEEDS
    for seed in (3, 0, 3):  # the same seed again, after other scenes: the same family and the same scene
        env.reset(seed=seed)
        assert env.scene_params == seen[seed][1]
    # each family's values lie in its own ranges
    from envs.tasks.unscrew_mixed import FLASK, WIDE_LID

    for family, params in seen.values():
        spec = (FLASK, WIDE_LID)[family]
        assert spec.cap_radius[0] <= params["cap_radius"] <= spec.cap_radius[1]
        assert spec.breakaway_torque[0] <= params["breakaway_torque"] <= spec.breakaway_torque[1]


@pytest.mark.sim
def test_each_family_needs_its_own_plan(env, executor, monkeypatch) -> None:
    """On a scene of each family its expert opens the cap and the other family's expert does not (measured on 30
    scenes of each family: own expert 30/30 and 30/30, the other's 0/30 and 0/30)."""
    from honesty import no_state_writes

    plans = _cls().family_expert_plans
    for family, seed in UNSCREW_SEEDS.items():
        executor.observe(seed=seed)
        assert env.scene_params["family"] == family
        with no_state_writes(monkeypatch) as writes:
            own = executor.run(plans[family])
        assert writes == []
        assert own.success and own.outcome["cap_turn_deg"] > 8.0 and own.outcome["gripped"], (family, own.outcome)
        other = executor.run(plans[1 - family], seed=seed)
        assert not other.success, (family, other.outcome)


@pytest.mark.sim
def test_x_tells_the_families_apart(env, executor, pointnet_path) -> None:
    """The meshes rebuilt from scene_params (the base task's builders) differ in size between the families: the
    cap across (tool cloud) and the body across (object cloud); so do their PointNet features. x_manip is
    recorded for both (the family index is in no part of x)."""
    import prl.shapes as S
    from prl.features import point_features
    from prl.pointnet import load_pointnet

    params, x_manip = {}, {}
    for family, seed in UNSCREW_SEEDS.items():
        x_manip[family] = executor.observe(seed=seed)
        params[family] = dict(env.scene_params)
    extents = {f: [m.extents for m in S.scene_meshes("unscrew_mixed", p)] for f, p in params.items()}
    assert extents[0][0][0] < 0.035 and extents[1][0][0] > 0.06  # the cap across: a small cap, a wide lid
    assert extents[0][1][0] > 0.10 and extents[1][1][0] < 0.06  # the body across: a wide flask, a narrow bottle
    for f, p in params.items():  # the variant's meshes are the base task's, from the same values
        base = S.scene_meshes("unscrew", p)
        np.testing.assert_allclose(extents[f][0], base[0].extents)
    assert x_manip[0].shape == x_manip[1].shape and np.isfinite(x_manip[0]).all()
    pointnet = load_pointnet(pointnet_path)
    tool, obj = point_features(pointnet, ["unscrew_mixed"] * 2, list(UNSCREW_SEEDS.values()),
                               [params[0], params[1]], 64)
    assert not np.allclose(tool[0], tool[1]) and not np.allclose(obj[0], obj[1])


@pytest.mark.sim
def test_open_fingers_and_a_cap_that_cannot_turn_fail_on_both_families(env, executor,
                                                                       monkeypatch) -> None:
    """The base task's honesty rules hold on the variant: each family's expert with its grasp's closed posture
    replaced by the open one (limp fingers) does not open the cap, nor does it on a cap whose thread holds 1000 N m
    (an immovable object); nothing is written to a pose while the plan runs."""
    from dataclasses import replace

    from honesty import no_state_writes

    from prl import stages as ex
    from prl.plb import load_plb

    cls = _cls()
    names = next(d.choices for d in load_plb().dims if d.name == "grasp_pattern")
    for family, seed in UNSCREW_SEEDS.items():
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
        assert not limp.success and abs(limp.outcome["cap_turn_deg"]) < 8.0, (family, limp.outcome)
    stuck = tuple(replace(spec, breakaway_torque=(1000.0, 1000.0)) for spec in cls.families)
    monkeypatch.setattr(cls, "families", stuck)
    for family, seed in UNSCREW_SEEDS.items():
        result = executor.run(cls.family_expert_plans[family], seed=seed)
        assert env.scene_params["family"] == family
        assert env.scene_params["breakaway_torque"] == 1000.0  # the scene was rebuilt from the patched table
        assert not result.success and abs(result.outcome["cap_turn_deg"]) < 8.0, (family, result.outcome)
