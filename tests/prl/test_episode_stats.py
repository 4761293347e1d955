"""prl.episode_stats gives lerobot's per-episode statistics bit for bit (values and dtypes)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("lerobot")

from lerobot.datasets.compute_stats import compute_episode_stats

from prl.episode_stats import fast_episode_stats


def _episode(rng: np.random.Generator, t: int) -> tuple[dict, dict]:
    data = {
        "state": rng.normal(size=(t, 30)).astype(np.float32),
        "wide": (rng.normal(size=(t, 4)) * 1e7).astype(np.float64),
        "constant": np.full((t, 3), 0.25, np.float32),
        "steps": np.repeat(rng.integers(0, 6, size=(t // 10 + 1, 6)), 10, axis=0)[:t].astype(np.int64),
        "index": np.arange(t, dtype=np.int64),
        "tiny": rng.normal(size=(t, 2)).astype(np.float32) * 1e-12,
        "binary": (rng.random(size=(t, 5)) < 0.5).astype(np.float32),  # q01 and q10 at the first edge: float32
        "mixed": np.concatenate([rng.normal(size=(t, 2)), np.full((t, 2), -3.0)], axis=1),  # flat and not: float64
        "ties": rng.integers(0, 3, size=(t, 4)).astype(np.float32),
        "near_flat": (1.0 + rng.random(size=(t, 2)) * 1e-6).astype(np.float32),  # edges repeat in float32
    }
    features = {k: {"dtype": str(v.dtype), "shape": v.shape[1:] or (1,)} for k, v in data.items()}
    return data, features


@pytest.mark.parametrize("t", [2, 3, 150, 751])
def test_fast_stats_equal_lerobots_bit_for_bit(t: int) -> None:
    data, features = _episode(np.random.default_rng(t), t)
    want = compute_episode_stats(data, features)
    with fast_episode_stats():
        got = compute_episode_stats(data, features)
    assert got.keys() == want.keys()
    for key in want:
        assert got[key].keys() == want[key].keys()
        for stat in want[key]:
            a, b = np.asarray(got[key][stat]), np.asarray(want[key][stat])
            assert a.dtype == b.dtype and a.shape == b.shape, (key, stat)
            assert a.tobytes() == b.tobytes(), (key, stat, a, b)


def test_lerobots_class_comes_back_after_the_block() -> None:
    from lerobot.datasets import compute_stats

    before = compute_stats.RunningQuantileStats
    with pytest.raises(RuntimeError), fast_episode_stats():
        assert compute_stats.RunningQuantileStats is not before
        raise RuntimeError("a failed write")
    assert compute_stats.RunningQuantileStats is before


def test_a_second_update_is_lerobots_running_update() -> None:
    """After the first (sparse) update, a second batch that widens the range goes through lerobot's own code on the
    dense histograms: the same statistics as lerobot's class fed the same two batches."""
    from lerobot.datasets import compute_stats

    rng = np.random.default_rng(3)
    first, second = rng.normal(size=(40, 6)).astype(np.float32), rng.normal(size=(25, 6)).astype(np.float32) * 3
    want = compute_stats.RunningQuantileStats()
    with fast_episode_stats():
        got = compute_stats.RunningQuantileStats()
    for stats in (want, got):
        stats.update(first)
        stats.update(second)
    a, b = got.get_statistics(), want.get_statistics()
    assert a.keys() == b.keys()
    for stat in b:
        assert a[stat].dtype == b[stat].dtype and a[stat].tobytes() == b[stat].tobytes(), stat


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_lin_edges_are_linspaces_row_by_row(dtype: type) -> None:
    """``LinEdges.at`` gives ``np.linspace``'s edges bit for bit: ordinary ranges, ranges the dtype cannot split in
    5,000 (repeated edges), all-equal ends and ends 1e-10 apart around 0."""
    from prl.episode_stats import LinEdges

    rng = np.random.default_rng(0)
    lo = np.concatenate([rng.normal(size=20) * 10.0 ** rng.integers(-3, 7, size=20), [2.0, 1.0, -1e-10, 7.0]])
    hi = np.concatenate([lo[:20] + rng.random(size=20) * 10.0 ** rng.integers(-12, 3, size=20), [2.0, 1.0 + 1e-6,
                                                                                             1e-10, 7.25]])
    lo, hi = lo.astype(dtype), hi.astype(dtype)
    edges = LinEdges(lo, hi, 5000)
    for i in range(lo.shape[0]):
        want = np.linspace(lo[i], hi[i], 5001)
        got = edges.at(np.broadcast_to(np.arange(5001)[:, None], (5001, lo.shape[0])))[:, i]
        assert got.dtype == want.dtype == dtype and got.tobytes() == want.tobytes(), (i, lo[i], hi[i])
        assert edges.row(i).tobytes() == want.tobytes()
