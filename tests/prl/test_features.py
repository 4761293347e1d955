"""RN features: the held-out split by scene seed, and the assembled x layout."""

from __future__ import annotations

import numpy as np
import pytest

from prl.features import FEATURE_LAYOUT, split_by_seed


def test_layout_is_x_manip_text_tool_object():
    assert [name for name, _ in FEATURE_LAYOUT.segments] == ["x_manip", "text", "tool_points", "object_points"]
    assert FEATURE_LAYOUT.dim == 784 + 384 + 256 + 256 == 1680


def test_split_holds_scenes_out_deterministically():
    seeds = np.array([5, 9, 5, 12, 40, 41, 42, 43, 44, 45])  # seed 5 twice: the same scene
    train, val = split_by_seed(seeds, 0.2, salt=1)
    assert sorted(np.concatenate([train, val]).tolist()) == list(range(10))
    assert not set(seeds[train]) & set(seeds[val])
    assert len(np.unique(seeds[val])) == 2  # round(0.2 * 9 scenes)
    again = split_by_seed(seeds, 0.2, salt=1)
    assert np.array_equal(again[0], train) and np.array_equal(again[1], val)
    many = np.arange(100, 200)
    assert not np.array_equal(split_by_seed(many, 0.2, salt=1)[1], split_by_seed(many, 0.2, salt=2)[1])


def test_split_errors_name_the_problem():
    with pytest.raises(ValueError, match="at least 2 scenes"):
        split_by_seed(np.array([3, 3]), 0.2)
    with pytest.raises(ValueError, match="val_fraction must be in"):
        split_by_seed(np.array([1, 2, 3]), 1.5)
    train, val = split_by_seed(np.array([1, 2]), 0.01)  # tiny fraction still leaves one on each side
    assert len(train) == 1 and len(val) == 1


def test_missing_dataset_is_named(tmp_path):
    from prl.features import read_episodes

    with pytest.raises(FileNotFoundError, match="no LeRobot dataset at .*nowhere"):
        read_episodes(tmp_path / "nowhere", "prl/hammer")
