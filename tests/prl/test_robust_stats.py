"""The rliable statistics (interquartile mean, stratified bootstrap, probability of improvement) against values
computed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from prl.robust_stats import (
    improvement_probability,
    iqm,
    probability_of_improvement,
    run_scores,
    stratified_bootstrap_ci,
)


def test_iqm_hand_computed() -> None:
    assert iqm([0, 1, 2, 3, 4, 5, 6, 7]) == 3.5  # int(0.25 * 8) = 2 cut each side: mean of 2, 3, 4, 5
    assert iqm([7, 0, 6, 1, 5, 2, 4, 3]) == 3.5  # order does not matter
    assert iqm([0, 0, 1, 10]) == 0.5  # one cut each side: mean of 0 and 1
    assert iqm([1, 2, 9]) == 4.0  # int(0.75) = 0: nothing cut, the mean (3 seeds)
    assert iqm([0, 1, 2, 3, 100]) == 2.0  # int(1.25) = 1: mean of 1, 2, 3 (5 seeds)
    assert iqm([[0, 1], [2, 3]]) == 1.5  # all scores, flattened
    assert list(iqm(np.array([[0, 1, 2, 3], [4, 4, 4, 40]]), axis=-1)) == [1.5, 4.0]  # row by row
    with pytest.raises(ValueError, match="no score"):
        iqm([])


def test_iqm_is_rliables_aggregate_iqm() -> None:
    """rliable's ``aggregate_iqm`` is ``scipy.stats.trim_mean(scores, 0.25, axis=None)``."""
    stats = pytest.importorskip("scipy.stats")
    rng = np.random.default_rng(3)
    for n in range(1, 30):
        x = rng.normal(size=n)
        assert iqm(x) == pytest.approx(stats.trim_mean(x, 0.25, axis=None), abs=1e-12)


def test_probability_of_improvement_hand_computed() -> None:
    # X = [1, 2], Y = [0, 2]: (1 > 0) 1, (1 > 2) 0, (2 > 0) 1, (2 = 2) 1/2 -> 2.5 / 4
    assert improvement_probability([1, 2], [0, 2]) == 0.625
    assert improvement_probability([1, 2], [1, 2]) == 0.5  # the same runs: no improvement either way
    assert improvement_probability([3], [1, 2, 3, 4]) == (1 + 1 + 0.5 + 0) / 4
    with pytest.raises(ValueError, match="runs on both sides"):
        improvement_probability([], [1])
    # two tasks: a scores P = 1 (all of X above Y), b P = 0; the mean over tasks is 0.5; runs of per-scene scores
    est, lo, hi = probability_of_improvement({"a": [[1, 1], [1, 0]], "b": [[0, 0]]},
                                             {"a": [[0, 0]], "b": [[1, 0], [1, 1]]}, reps=500, resample_scenes=False)
    assert est == 0.5 and lo == hi == 0.5  # whatever runs are drawn, a stays at 1 and b at 0
    with pytest.raises(ValueError, match="same tasks"):
        probability_of_improvement({"a": [[1]]}, {"b": [[0]]})


def test_stratified_bootstrap_hand_computed() -> None:
    # one run per task, scenes kept: every draw is the same runs, so the interval is the estimate
    est, lo, hi = stratified_bootstrap_ci({"a": [[1, 1, 0, 1]], "b": [[0, 1]]}, reps=200, resample_scenes=False)
    assert est == lo == hi == pytest.approx(0.625)  # IQM (mean, nothing cut) of 0.75 and 0.5
    # run scores 0 and 1 in one task: a draw of two runs averages to 0 (1/4), 0.5 (1/2) or 1 (1/4), so the 95%
    # interval spans 0 to 1 around the estimate 0.5
    est, lo, hi = stratified_bootstrap_ci({"a": [[0, 0], [1, 1]]}, reps=4000, resample_scenes=False)
    assert (est, lo, hi) == (0.5, 0.0, 1.0)
    # strata: runs are resampled within each task, never across, so a task whose runs agree adds no spread
    _, lo, hi = stratified_bootstrap_ci({"a": [[1], [1], [1]], "b": [[0], [0], [0]]}, reps=500)
    assert lo == hi == 0.5
    assert run_scores({"a": [[1, 0, 0, 1], [1]]})["a"].tolist() == [0.5, 1.0]


def test_bootstrap_is_deterministic_and_scenes_widen_the_interval() -> None:
    rng = np.random.default_rng(0)
    runs = {t: [rng.integers(0, 2, size=50).tolist() for _ in range(3)] for t in ("hammer", "sweep")}
    first = stratified_bootstrap_ci(runs, reps=2000, seed=7)
    assert stratified_bootstrap_ci(runs, reps=2000, seed=7) == first
    assert stratified_bootstrap_ci(runs, reps=2000, seed=8) != first
    seeds_only = stratified_bootstrap_ci(runs, reps=2000, seed=7, resample_scenes=False)
    assert seeds_only[0] == first[0] and first[2] - first[1] > seeds_only[2] - seeds_only[1]
    other = {t: [rng.integers(0, 2, size=50).tolist() for _ in range(3)] for t in runs}
    assert probability_of_improvement(runs, other, reps=500, seed=1) == \
        probability_of_improvement(runs, other, reps=500, seed=1)


@pytest.mark.parametrize(("runs", "kwargs", "match"), [
    ({"a": []}, {}, "task 'a' has no run"),
    ({"a": [[1], []]}, {}, "task 'a': run 1 has no scene score"),
    ({"a": [[1]]}, {"reps": 0}, "reps must be an integer >= 1, got 0"),
    ({"a": [[1]]}, {"level": 1.0}, r"level must be in \(0, 1\), got 1.0"),
])
def test_bad_input_is_named(runs: dict, kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        stratified_bootstrap_ci(runs, **kwargs)
