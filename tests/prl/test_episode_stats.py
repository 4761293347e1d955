"""prl.episode_stats gives lerobot's per-episode statistics bit for bit (values and dtypes)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("lerobot")

from lerobot.datasets.compute_stats import compute_episode_stats  # noqa: E402

from prl.episode_stats import fast_episode_stats  # noqa: E402


def _episode(rng: np.random.Generator, t: int) -> tuple[dict, dict]:
    data = {
        "state": rng.normal(size=(t, 30)).astype(np.float32),
        "wide": (rng.normal(size=(t, 4)) * 1e7).astype(np.float64),
        "constant": np.full((t, 3), 0.25, np.float32),
        "steps": np.repeat(rng.integers(0, 6, size=(t // 10 + 1, 6)), 10, axis=0)[:t].astype(np.int64),
        "index": np.arange(t, dtype=np.int64),
        "tiny": rng.normal(size=(t, 2)).astype(np.float32) * 1e-12,
        "binary": (rng.random(size=(t, 5)) < 0.5).astype(np.float32),  # q01 and q10 at the first edge: float32
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


def test_lerobots_methods_come_back_after_the_block() -> None:
    from lerobot.datasets.compute_stats import RunningQuantileStats

    before = RunningQuantileStats._update_histograms, RunningQuantileStats._compute_quantiles
    with pytest.raises(RuntimeError), fast_episode_stats():
        assert RunningQuantileStats._compute_quantiles is not before[1]
        raise RuntimeError("a failed write")
    assert (RunningQuantileStats._update_histograms, RunningQuantileStats._compute_quantiles) == before
