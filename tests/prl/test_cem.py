"""The cross-entropy method over plans, on hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from prl import cem


def test_update_by_hand() -> None:
    """Two dimensions of sizes 2 and 3; elites [0, 2], [0, 1]: frequencies (1, 0) and (0, .5, .5)."""
    probs = cem.uniform([2, 3])
    new = cem.update(probs, np.array([[0, 2], [0, 1]]), smoothing=0.5)
    np.testing.assert_allclose(new[0], [0.75, 0.25])  # 0.5 * (1, 0) + 0.5 * (.5, .5)
    np.testing.assert_allclose(new[1], [1 / 6, 0.25 + 1 / 6, 0.25 + 1 / 6])


def test_the_floor_keeps_every_choice_alive() -> None:
    """Smoothing 1 puts all mass on the elites' choice; a floor of 0.2 x uniform (1/4) keeps 0.05 on each other
    choice before renormalising: (1, .05, .05, .05) / 1.15."""
    new = cem.update(cem.uniform([4]), np.array([[0], [0]]), smoothing=1.0, floor=0.2)
    np.testing.assert_allclose(new[0], np.array([1.0, 0.05, 0.05, 0.05]) / 1.15)
    prior = [np.array([0.7, 0.3, 0.0, 0.0])]  # a reference that forbids choices 2, 3: they may die out
    new = cem.update(cem.uniform([4]), np.array([[0]]), smoothing=1.0, reference=prior, floor=0.2)
    np.testing.assert_allclose(new[0], np.array([1.0, 0.06, 0.0, 0.0]) / 1.06)


def test_elites_and_sampling() -> None:
    plans = np.array([[0], [1], [2], [3]])
    np.testing.assert_array_equal(cem.elites(plans, np.array([1.0, 5.0, 5.0, 0.0]), 0.5), [[1], [2]])
    np.testing.assert_array_equal(cem.elites(plans, np.zeros(4), 0.01), [[0]])  # at least one, ties stable
    drawn = cem.sample([np.array([0.0, 1.0]), np.array([0.5, 0.5])], 2000, np.random.default_rng(0))
    assert drawn.shape == (2000, 2) and np.all(drawn[:, 0] == 1) and abs(drawn[:, 1].mean() - 0.5) < 0.05


def test_the_search_climbs_a_bandit() -> None:
    """A 3-dimensional bandit that pays only for plan (2, 0, 1): a few rounds find it from uniform."""
    rng = np.random.default_rng(1)
    probs = cem.uniform([3, 3, 3])
    for _ in range(6):
        plans = cem.sample(probs, 64, rng)
        scores = (plans == [2, 0, 1]).sum(axis=1).astype(float)
        probs = cem.update(probs, cem.elites(plans, scores, 0.2), smoothing=0.7, floor=0.1)
    assert [int(np.argmax(p)) for p in probs] == [2, 0, 1] and min(p.max() for p in probs) > 0.8


@pytest.mark.parametrize(("kwargs", "match"), [({"smoothing": 1.5}, "smoothing"), ({"floor": 1.0}, "floor")])
def test_bad_settings_are_named(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        cem.update(cem.uniform([2]), np.array([[0]]), **kwargs)
    with pytest.raises(ValueError, match="elite fraction"):
        cem.elites(np.array([[0]]), np.array([1.0]), 0.0)
