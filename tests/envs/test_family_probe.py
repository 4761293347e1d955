"""``envs.family_probe``: the family ranges swapped for a probe and put back, and its errors."""

from __future__ import annotations

import pytest

from envs.family_probe import (
    PlanRecord,
    changed_family,
    family_ranges,
    main,
    parse_setting,
    plan_record,
    reward_traps,
)
from envs.tasks.unscrew_mixed import FLASK, WIDE_LID, PRLUnscrewMixedEnv


def test_parse_setting() -> None:
    assert parse_setting("cube_size=0.029,0.032") == ("cube_size", (0.029, 0.032))
    for bad in ("cube_size", "cube_size=0.029", "cube_size=a,b", "=0.1,0.2", "cube_size=0.1,0.2,0.3"):
        with pytest.raises(ValueError, match="expected field=low,high"):
            parse_setting(bad)


def test_changed_family_keeps_the_other_ranges_and_names_an_unknown_field() -> None:
    spec = changed_family(WIDE_LID, {"breakaway_torque": (4.2, 4.8)})
    assert spec.breakaway_torque == (4.2, 4.8)
    assert spec.cap_radius == WIDE_LID.cap_radius and spec.name == "wide_lid"
    with pytest.raises(ValueError, match="has no field 'cube_size'"):
        changed_family(WIDE_LID, {"cube_size": (0.02, 0.03)})
    with pytest.raises(ValueError, match="breakaway_torque must be a range"):  # the record's own check
        changed_family(WIDE_LID, {"breakaway_torque": (4.8, 4.2)})


def test_family_ranges_swap_every_slot_and_restore_the_table_even_on_error() -> None:
    table = PRLUnscrewMixedEnv.families
    assert table == (FLASK, WIDE_LID)
    with family_ranges(PRLUnscrewMixedEnv, 1, {"breakaway_torque": (4.2, 4.8)}) as spec:
        assert PRLUnscrewMixedEnv.families == (spec, spec)
        assert spec.breakaway_torque == (4.2, 4.8)
    assert PRLUnscrewMixedEnv.families == table
    with pytest.raises(RuntimeError, match="boom"), family_ranges(PRLUnscrewMixedEnv, 0, {}):
        raise RuntimeError("boom")
    assert PRLUnscrewMixedEnv.families == table
    with pytest.raises(ValueError, match="families 0..1, not 2"), family_ranges(PRLUnscrewMixedEnv, 2, {}):
        pass


def test_cli_names_bad_input(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["--task", "unscrew_mixed", "--family", "1", "--plans", "0,3,2,0,5"])
    assert "6 entries" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--task", "unscrew", "--family", "0", "--plans", "0,3,2,0,5,1", "--scenes", "1"])
    assert "no scene families" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--task", "unscrew_mixed", "--family", "1", "--set", "cube_size=0.1,0.2", "--plans", "0,3,2,0,5,1"])
    assert "has no field 'cube_size'" in capsys.readouterr().err


def test_cli_needs_plans_or_prior(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["--task", "unscrew_mixed", "--family", "1"])
    assert "give --plans, or --prior N" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--task", "unscrew_mixed", "--family", "1", "--prior", "-3"])
    assert "--prior -3" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--task", "unscrew", "--family", "0", "--prior", "2", "--scenes", "1"])
    assert "no scene families" in capsys.readouterr().err


def test_prior_decodings_decode_the_successes_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """The physics stands in for a rule here (a plan succeeds when its a4 is 2): the plumbing from the prior's
    draws to the decoded plans, not the simulator, is under test."""
    from types import SimpleNamespace

    import envs.trials
    from envs.family_probe import prior_decodings

    seen: dict[str, list] = {}

    def rule(task, plans, seeds, **_):
        seen["plans"], seen["seeds"] = list(plans), list(seeds)
        assert PRLUnscrewMixedEnv.families[0].name == "wide_lid"  # drawn from the probed family only
        return [SimpleNamespace(success=p[4] == 2) for p in plans]

    monkeypatch.setattr(envs.trials, "run_trials", rule)
    won, decoded = prior_decodings("unscrew_mixed", 1, {}, [7, 8, 9], 40, rng_seed=3)
    assert seen["seeds"] == [7, 8, 9] * 13 + [7]
    successes = [p for p in seen["plans"] if p[4] == 2]
    assert won == len(successes) > 0
    assert set(decoded) == {"rn", "rn_library", "rn_success"}
    assert decoded["rn"][4] == 2 and decoded["rn_library"] in successes and decoded["rn_success"] in successes
    for d in range(6):  # the per-dimension mode of the successes, first choice on a tie
        counts = [sum(p[d] == c for p in successes) for c in range(max(p[d] for p in successes) + 1)]
        assert decoded["rn"][d] == counts.index(max(counts))
    monkeypatch.setattr(envs.trials, "run_trials",
                        lambda task, plans, seeds, **_: [SimpleNamespace(success=False)] * len(plans))
    with pytest.raises(ValueError, match="none of the 5 prior-sampled plans succeeded on family 1"):
        prior_decodings("unscrew_mixed", 1, {}, [7], 5, rng_seed=3)


def test_plan_record_averages_the_reward_over_successes_and_failures() -> None:
    from types import SimpleNamespace

    outs = [SimpleNamespace(success=True, measure=70.0), SimpleNamespace(success=False, measure=0.5),
            SimpleNamespace(success=True, measure=60.0), SimpleNamespace(success=False, measure=-2.5)]
    rec = plan_record([0, 3, 2, 3, 5, 1], outs)
    assert rec == PlanRecord((0, 3, 2, 3, 5, 1), 2, 4, 32.0)  # (70 + 0.5 + 60 - 2.5) / 4
    assert rec.rate == 0.5
    assert plan_record([0, 3, 2, 3, 5, 1], []).mean_reward == 0.0


def test_reward_traps_are_the_better_paid_less_successful_plans() -> None:
    """The unscrew_mixed flasks (docs/guide/tasks.md): the anchor-2 disk opens 20/20 turning the cap 65 deg; the anchor-1
    disk 18/20 at 114 deg on average, a push that spins the cap 0/20 at 158 deg: both are traps; a plan paid less
    (a wrap, 0/20 at 3 deg) and one as successful but paid more are not."""
    disk2 = PlanRecord((0, 3, 2, 3, 5, 1), 20, 20, 65.0)
    disk1 = PlanRecord((0, 3, 1, 3, 5, 1), 18, 20, 114.0)
    push = PlanRecord((4, 3, 1, 3, 2, 3), 0, 20, 158.0)
    wrap = PlanRecord((0, 3, 2, 0, 5, 1), 0, 20, 3.0)
    assert reward_traps([wrap, disk1, disk2, push]) == [disk1, push]
    assert reward_traps([disk2, wrap]) == []
    twin = PlanRecord((1, 3, 2, 3, 5, 1), 20, 20, 80.0)  # as successful, paid more: it is the best, disk2 no trap
    assert reward_traps([disk2, twin, disk1]) == [disk1]  # 114 > 80 with 18/20 < 20/20
    assert reward_traps([]) == []
