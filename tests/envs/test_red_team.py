"""The red-team search and the label check: what they report, and bad arguments named."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.parametrize(("module", "argv", "named"), [
    ("envs.red_team", ["--tasks", "hamer"], "'hamer'"),
    ("envs.red_team", ["--rounds", "0"], "--rounds must be >= 1, got 0"),
    ("envs.label_check", ["--kinds", "expert,bogus"], "bogus"),
    ("envs.label_check", ["--scenes", "0"], "--scenes must be >= 1, got 0"),
])
def test_bad_arguments_are_named(module: str, argv: list[str], named: str, capsys) -> None:
    import importlib

    with pytest.raises(SystemExit) as exc:
        importlib.import_module(module).main(argv)
    assert exc.value.code == 2 and named in capsys.readouterr().err


def test_label_table_marks_unacted_dimensions_and_lists_misses() -> None:
    from envs.label_check import markdown, misses

    frac = np.array([1.0, 1.0, 0.5, 1.0, 1.0, 0.0])
    text = markdown([("unscrew", "prior", frac, 2, 10, ["a2: 1 -> 2 x1"])], "cmd")
    row = next(line for line in text.splitlines() if line.startswith("| unscrew"))
    assert row == "| unscrew | prior | 2/10 | 100% | 100% | 50% | 100% | 100% | n/a | 90% |"  # (1+1+.5+1+1)/5
    assert "- unscrew prior: a2: 1 -> 2 x1" in text
    assert misses(np.array([[0, 0, 1, 0, 0, 0], [0, 0, 1, 0, 0, 0]]), np.array([[0, 0, 2, 0, 0, 0], [0, 0, 1, 0, 0, 0]])) \
        == ["a2: 1 -> 2 x1"]


@pytest.mark.sim
def test_a_tiny_search_reports_its_rounds_and_rechecks_what_it_found() -> None:
    from envs.red_team import evidence, report, search

    result = search("unscrew", rounds=2, per_round=6, top_k=2, check_scenes=2)
    assert len(result.attempts) == 12 and len(result.round_rates) == 2
    assert all(sum(p) == pytest.approx(1.0) for p in result.final_probs)
    for top in result.top:  # each re-run plan was found successful at least once
        assert top["found"] >= 1 and len(top["checks"]) == 2
        assert all(set(row["evidence"]) == set(evidence("unscrew")) for row in top["checks"])
    text = report([result], "cmd")
    assert text.count("\n| `[") == len(result.top) and "## unscrew" in text
