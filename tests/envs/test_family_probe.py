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
