"""envs.families and the per-family reports of the RN (Fig 7's rows, its evaluation): hand-computed cases, the
oracle on real scenes of unscrew_mixed, and bad input named."""

from __future__ import annotations

from types import SimpleNamespace

import pytest


def _outcome(success: bool, plan: tuple[int, ...] = (0, 0, 0, 0, 0, 0)) -> SimpleNamespace:
    return SimpleNamespace(success=success, plan=plan)


def test_per_family_and_frequent_plans_by_hand() -> None:
    from envs.families import frequent_plans, per_family

    outs = [_outcome(s) for s in (True, False, True, True, False)]
    assert per_family(outs, [1, 0, 0, 1, 1]) == {0: (1, 2), 1: (2, 3)}
    with pytest.raises(ValueError, match="5 outcomes but 4 families"):
        per_family(outs, [0, 0, 1, 1])
    plans = [(1, 2), (3, 4), (1, 2), (5, 6), (3, 4), (1, 2)]
    assert frequent_plans(plans, 2) == [((1, 2), 3), ((3, 4), 2)]
    assert frequent_plans(plans, 9) == [((1, 2), 3), ((3, 4), 2), ((5, 6), 1)]
    with pytest.raises(ValueError, match="top must be >= 1, got 0"):
        frequent_plans(plans, 0)


def test_family_decodings_by_hand() -> None:
    """A family-exact RN's plans, computed by hand: family 1's weighted marginals are [.32, .40, .28] and [.4, .6],
    so the argmax (1, 1) was never demonstrated; the library's best is (0, 1) (.32 * .6 = .192 against (1, 0)'s .16 and
    (2, 1)'s .168); divided by the prior [.5, .25, .25] x [.8, .2] the best is (2, 1) (3.36 against 1.92 and 0.8)."""
    import numpy as np

    from envs.families import family_decodings

    plans = [(0, 1), (2, 1), (1, 0), (0, 1), (2, 1)]
    families = [0, 0, 1, 1, 1]
    weights = [1.0, 3.0, 2.0, 1.6, 1.4]
    prior = (np.array([0.5, 0.25, 0.25]), np.array([0.8, 0.2]))
    assert family_decodings(plans, families, weights, prior) == {
        0: {"rn": (2, 1), "rn_library": (2, 1), "rn_success": (2, 1)},
        1: {"rn": (1, 1), "rn_library": (0, 1), "rn_success": (2, 1)},
    }
    with pytest.raises(ValueError, match=r"outside the prior's sizes \[3, 2\]: dimension, choice \[\(0, 3\)\]"):
        family_decodings([(3, 0)], [0], [1.0], prior)
    with pytest.raises(ValueError, match=r"dimension, choice \[\(1, -1\)\]"):
        family_decodings([(0, -1), (1, 1)], [0, 0], [1.0, 1.0], prior)
    with pytest.raises(ValueError, match=r"plans must have shape \(N >= 1, 2\), got \(1, 3\)"):
        family_decodings([(0, 0, 0)], [0], [1.0], prior)
    with pytest.raises(ValueError, match="weights must be finite and >= 0"):
        family_decodings(plans, families, [1.0, -1.0, 1.0, 1.0, 1.0], prior)
    with pytest.raises(ValueError, match=r"one value per plan \(5\)"):
        family_decodings(plans, families[:4], weights, prior)


def test_families_are_read_back_from_the_oracles_plans() -> None:
    from envs.families import families_of_oracle, family_plans

    plans = family_plans("unscrew_mixed")
    assert plans == {0: (0, 3, 2, 3, 5, 1), 1: (4, 3, 4, 0, 5, 1)}
    assert family_plans("unscrew") is None
    oracle = [_outcome(True, plans[1]), _outcome(False, plans[0]), _outcome(True, plans[1]), _outcome(False, ())]
    assert families_of_oracle("unscrew_mixed", oracle) == [1, 0, 1, -1]  # -1: the scene raised before a plan
    with pytest.raises(ValueError, match="task 'hammer' has no scene families"):
        families_of_oracle("hammer", oracle)
    with pytest.raises(ValueError, match="unknown task 'hamer'"):
        family_plans("hamer")


def test_fig7_rows_put_a_mixed_variants_families_apart() -> None:
    from flows.compute_features import scene_families
    from flows.train_rn import figure_groups

    assert scene_families([{"cap_radius": 0.02}, {"family": 1.0, "cap_radius": 0.03}, {"family": 0.0}]) == [-1, 1, 0]
    groups = figure_groups(["hammer", "unscrew_mixed", "hammer", "unscrew_mixed", "unscrew_mixed"],
                           [-1, 1, -1, 0, 1])
    assert list(groups) == ["hammer", "unscrew_mixed", "unscrew_mixed family 0", "unscrew_mixed family 1"]
    assert [g.tolist() for g in groups.values()] == [[0, 2], [1, 3, 4], [3], [1, 4]]
    with pytest.raises(ValueError, match="3 tasks but 2 families"):
        figure_groups(["a", "b", "c"], [0, 1])


def test_demo_counts_per_family_with_their_effective_sample_size() -> None:
    import numpy as np

    from flows.train_rn import demo_counts, figure_groups

    groups = figure_groups(["unscrew_mixed"] * 3, [0, 1, 1])
    counts = demo_counts(groups, np.array([2.0, 1.0, 3.0]))
    # Kish by hand: all (2+1+3)^2 / (4+1+9) = 36/14; family 0 one demo; family 1 (1+3)^2 / (1+9) = 1.6
    assert counts["unscrew_mixed"][0] == 3 and abs(counts["unscrew_mixed"][1] - 36 / 14) < 1e-12
    assert counts["unscrew_mixed family 0"] == (1, 1.0)
    assert counts["unscrew_mixed family 1"][0] == 2 and abs(counts["unscrew_mixed family 1"][1] - 1.6) < 1e-12


def test_the_rn_evaluation_reports_each_family(monkeypatch, capsys) -> None:
    """log_rn_eval with an oracle kind: per-family successes of every kind, printed and logged, by hand."""
    import mlflow

    from flows.evaluate_rn import log_rn_eval

    logged: dict[str, float] = {}
    monkeypatch.setattr(mlflow, "log_metrics", lambda m, **kw: logged.update(m))
    monkeypatch.setattr(mlflow, "log_metric", lambda k, v, **kw: logged.update({k: v}))
    dicts = {}
    monkeypatch.setattr(mlflow, "log_dict", lambda d, name: dicts.update({name: d}))
    f0, f1 = (0, 3, 2, 3, 5, 1), (4, 3, 4, 0, 5, 1)
    oracle = [_outcome(True, f0), _outcome(True, f1), _outcome(False, f1), _outcome(True, f0)]
    for o, seed in zip(oracle, range(4), strict=True):
        o.seed, o.measure, o.fault, o.error = seed, 1.0, "", ""
    rn = [SimpleNamespace(success=s, plan=f0, seed=i, measure=0.0, fault="", error="")
          for i, s in enumerate((True, False, False, True))]
    rates = log_rn_eval("unscrew_mixed", "train_ranges", {"rn": rn, "oracle": oracle})
    assert rates == {"rn": 0.5, "oracle": 0.75}
    assert logged["unscrew_mixed/train_ranges/rn_family0_success_rate"] == 1.0  # scenes 0 and 3: both succeeded
    assert logged["unscrew_mixed/train_ranges/rn_family1_success_rate"] == 0.0
    assert logged["unscrew_mixed/train_ranges/oracle_family1_success_rate"] == 0.5
    assert "family 0: 2/2, family 1: 0/2" in capsys.readouterr().out
    assert [r["family"] for r in dicts["unscrew_mixed_train_ranges_rn_eval.json"]["rn"]] == [0, 1, 1, 0]


@pytest.mark.sim
def test_the_oracle_runs_each_scenes_own_family_plan() -> None:
    from envs.families import families_of_oracle, oracle_outcomes

    outcomes = oracle_outcomes("unscrew_mixed", [0, 1])
    families = families_of_oracle("unscrew_mixed", outcomes)
    assert families == [0, 1]  # seed 0 a flask, seed 1 a wide lid (tests/envs/test_unscrew_mixed.py)
    assert [o.plan for o in outcomes] == [(0, 3, 2, 3, 5, 1), (4, 3, 4, 0, 5, 1)]
    assert all(o.success for o in outcomes)
    with pytest.raises(ValueError, match="task 'unscrew' has no scene families"):
        oracle_outcomes("unscrew", [0])


def test_the_command_names_bad_input(capsys) -> None:
    from envs.families import main

    for argv, named in ((["--task", "unscrew"], "task 'unscrew' has no scene families"),
                        (["--task", "hamer"], "unknown task 'hamer'"),
                        (["--task", "unscrew_mixed", "--scenes", "0"], "--scenes must be >= 1, got 0"),
                        (["--task", "unscrew_mixed", "--dataset-root", "/nonexistent/d"],
                         "no exported dataset there"),
                        (["--task", "unscrew_mixed", "--uniform", "--dataset-root", "/nonexistent/d"],
                         "--uniform runs the uniform plans instead of the family table"),
                        (["--task", "unscrew_mixed", "--decodings"], "--decodings reads the demos: give --dataset-root")):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2 and named in capsys.readouterr().err, argv


@pytest.mark.sim
def test_the_command_prints_the_oracle_and_the_best_fixed_plan(capsys) -> None:
    """Trial scenes 0 and 1 (run seed 0) are a flask and a wide lid: the oracle opens both, each family's plan one."""
    from envs.families import main

    assert main(["--task", "unscrew_mixed", "--scenes", "2"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "unscrew_mixed on 2 trial scenes (families: {0: 1, 1: 1})"
    assert out[1].startswith("oracle ") and "2/2 = 1.00" in out[1] and out[1].endswith("family 0: 1/1; family 1: 1/1")
    assert "1/2 = 0.50" in out[2] and out[2].endswith("family 0: 1/1; family 1: 0/1")
    assert "1/2 = 0.50" in out[3] and out[3].endswith("family 0: 0/1; family 1: 1/1")
    assert out[4].startswith("best single fixed plan of 2: family 0 expert")


@pytest.mark.sim
def test_uniform_plans_are_the_trials_own_split_per_family() -> None:
    """The uniform plans on the scenes of `envs.trials --kinds uniform`: the same outcomes as the trials, and each
    scene's family the one the oracle reads back on that scene."""
    from envs.families import families_of_oracle, oracle_outcomes, uniform_outcomes
    from envs.trials import kind_seed, plan_set, run_trials, trial_scene_seeds

    outcomes, families = uniform_outcomes("unscrew_mixed", 3)
    seed = kind_seed(0, "uniform")
    seeds = trial_scene_seeds(seed, 3)
    trials = run_trials("unscrew_mixed", plan_set("unscrew_mixed", "uniform", 3, seed), seeds, progress=False)
    assert [(o.seed, o.plan, o.success) for o in outcomes] == [(o.seed, o.plan, o.success) for o in trials]
    assert families == families_of_oracle("unscrew_mixed", oracle_outcomes("unscrew_mixed", seeds))
    assert set(families) <= {0, 1}
