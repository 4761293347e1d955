"""``envs.family_probe``: the family ranges swapped for a probe and put back, and its errors."""

from __future__ import annotations

import pytest

from envs.family_probe import changed_family, family_ranges, main, parse_setting
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
