"""The pure parts of ``bench.bench_proposal``'s run-against-run table, on hand-computed cases."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bench.bench_proposal import kept_plans, main, share_gaps, shares_markdown


def _row(plan: list[int], success: bool, prior_logp: float, proposal_logp: float) -> dict:
    return {"plan": plan, "success": success, "prior_logp": prior_logp, "proposal_logp": proposal_logp}


def test_kept_plans_keep_the_successes_with_their_weights() -> None:
    rows = [_row([0, 1], True, math.log(0.5), math.log(0.25)),  # p / q = 2
            _row([1, 1], False, math.log(0.5), math.log(0.1)),  # a failure: not kept
            _row([1, 0], True, math.log(0.5), math.log(1.0))]  # p / q = 0.5
    plans, w = kept_plans(rows, 2)
    np.testing.assert_array_equal(plans, [[0, 1], [1, 0]])
    np.testing.assert_allclose(w, [1.6, 0.4])  # 2 and 0.5, scaled to mean 1


def test_share_gaps_weigh_each_side_by_its_own_weights() -> None:
    sizes = (2, 3)
    # this run: choice 0 of a0 kept 3 times with weight 1/3 each and choice 1 once with weight 1: weighted 0.5 / 0.5,
    # raw 0.75 / 0.25; a1 always choice 2
    mine = (np.array([[0, 2], [0, 2], [0, 2], [1, 2]]), np.array([1 / 3, 1 / 3, 1 / 3, 1.0]))
    # a prior-only run: a0 half and half, a1 choice 2 three times in four, choice 0 once
    theirs = (np.array([[0, 2], [1, 2], [0, 0], [1, 2]]), np.ones(4))
    assert share_gaps(mine, theirs, sizes) == pytest.approx([0.0, 0.25])
    assert share_gaps(mine, theirs, sizes, weighted=False) == pytest.approx([0.25, 0.25])


def test_shares_markdown_sets_this_run_against_each_prior_run_and_those_against_each_other() -> None:
    sizes = (2,)
    a = (np.array([[0], [1]]), np.array([0.5, 1.5]))  # weighted 0.25 / 0.75, raw 0.5 / 0.5
    p0 = (np.array([[1], [1], [0], [1]]), np.ones(4))  # 0.25 / 0.75
    p1 = (np.array([[0], [0]]), np.ones(2))  # 1.0 / 0.0
    lines = shares_markdown({"hammer": a}, {"p0": {"hammer": p0}, "p1": {"hammer": p1}}, sizes)
    assert lines[4:] == ["| hammer | this run, 2 | p0, 4 | 0.00 (max 0.00) | 0.25 (max 0.25) |",
                         "| hammer | this run, 2 | p1, 2 | 0.75 (max 0.75) | 0.50 (max 0.50) |",
                         "| hammer | p0, 4 | p1, 2 | 0.75 (max 0.75) | - |"]


def test_a_missing_prior_synthesis_dir_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "seed1-shards4-frames750-prior"
    assert main(["--synthesis-dir", str(tmp_path), "--prior-synthesis-dir", str(missing)]) == 2
    assert f"no synthesis directory at {str(missing)!r}" in capsys.readouterr().err
