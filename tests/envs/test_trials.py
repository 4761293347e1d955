"""``python -m envs.trials``: the one command that measures a task's success rates, with its own plan and measure."""

from __future__ import annotations

import numpy as np
import pytest

from prl.plb import PLBError, parse_plan


def test_parse_plan_reads_the_command_line_form_and_names_bad_text() -> None:
    assert parse_plan("0,3,2,0,0,1").tolist() == [0, 3, 2, 0, 0, 1]
    assert parse_plan(" 2, 1,4,2,6,0").dtype == np.int64
    with pytest.raises(PLBError, match="got '0,x,2'"):
        parse_plan("0,x,2")
    with pytest.raises(PLBError, match="out of range"):
        parse_plan("0,3,2,0,0,9")
    with pytest.raises(PLBError, match="6 entries"):
        parse_plan("0,3")


@pytest.mark.parametrize(("argv", "named"), [
    (["--task", "hamer"], "'hamer'"),
    (["--task", "sweep", "--kinds", "expert,bogus"], "bogus"),
    (["--task", "sweep", "--plan", "0,3,x"], "0,3,x"),
    (["--task", "sweep", "--scenes", "0"], "--scenes must be >= 1, got 0"),
])
def test_bad_arguments_stop_before_any_episode_naming_the_value(argv: list[str], named: str, capsys) -> None:
    from envs.trials import main

    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and named in capsys.readouterr().err


@pytest.mark.sim
def test_each_task_reports_its_own_expert_and_measure(capsys) -> None:
    from envs.trials import main

    main(["--task", "sweep", "--scenes", "1", "--kinds", "expert"])
    main(["--task", "unscrew", "--scenes", "1", "--plan", "0,3,2,0,6,1"])
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("sweep expert   1/1") and "mean cubes_in_zone" in out[0], out
    assert out[1].startswith("unscrew plan 0,3,2,0,6,1") and "cap_turn_deg" in out[1], out
