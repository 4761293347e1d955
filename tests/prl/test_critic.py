"""The success critic (prl.critic): AUC by hand, a synthetic task where the most often kept plan is not the most
reliable one, decoding among the RN's candidates, checkpoints and errors."""

from __future__ import annotations

import numpy as np
import pytest

from prl.critic import CriticConfig, auc, critic_plan, load_critic, save_critic, train_critic

DIMS = (3, 2)


def test_auc_by_hand():
    # positives 0.9, 0.4; negatives 0.1, 0.4, 0.8: pairs above 0.9>all 3, 0.4>0.1 and ties 0.4 (half) -> 4.5 / 6
    assert auc(np.array([1, 1, 0, 0, 0]), np.array([0.9, 0.4, 0.1, 0.4, 0.8])) == pytest.approx(4.5 / 6)
    assert auc(np.array([1, 0]), np.array([0.0, 1.0])) == 0.0
    assert np.isnan(auc(np.array([1, 1]), np.array([0.2, 0.3])))


def synthetic(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two families read from x[:, 0] > 0. Family 0: plan[0] = 0 succeeds 95%, 1 and 2 fail. Family 1: plan[0] = 1
    succeeds 90%, plan[0] = 2 succeeds 40%; plan[1] never matters. Plans drawn so that plan[0] = 2 is tried most."""
    x = rng.normal(size=(n, 4)).astype(np.float32)
    fam = (x[:, 0] > 0).astype(int)
    plans = np.stack([rng.choice(3, size=n, p=[0.2, 0.2, 0.6]), rng.integers(0, 2, size=n)], axis=1)
    p = np.where(fam == 0, np.where(plans[:, 0] == 0, 0.95, 0.0), np.select(
        [plans[:, 0] == 1, plans[:, 0] == 2], [0.9, 0.4], 0.0))
    return x, plans, rng.random(n) < p


@pytest.mark.train
def test_the_critic_ranks_by_success_not_by_how_often_kept():
    rng = np.random.default_rng(0)
    x, plans, success = synthetic(3000, rng)
    # among family 1's successes the 40% plan is kept more often than the 90% one (0.6 x 0.4 > 0.2 x 0.9)
    kept = plans[success & (x[:, 0] > 0), 0]
    assert (kept == 2).sum() > (kept == 1).sum()
    xv, pv, sv = synthetic(600, rng)
    critic, history = train_critic(x, plans, success, CriticConfig(epochs=30, hidden=32, dims=DIMS), xv, pv, sv,
                                   progress=False)
    best = min(history, key=lambda r: r["critic/val_loss"])
    assert best["critic/val_loss"] < best["critic/base_loss"] and best["critic/val_auc"] > 0.85
    library = np.array([[0, 0], [1, 0], [2, 0]])
    probe = np.array([[-1.0, 0, 0, 0], [1.0, 0, 0, 0]], dtype=np.float32)
    assert critic_plan(critic, probe, library).tolist() == [[0, 0], [1, 0]]
    # among the RN's top 2 only: where the RN ranks [2, 0] and [0, 0] first, the critic picks [0, 0] on family 0
    # and the only one of the two that works at all on family 1, [2, 0]
    rn_probs = [np.array([[0.3, 0.1, 0.6], [0.3, 0.1, 0.6]]), np.array([[0.5, 0.5], [0.5, 0.5]])]
    assert critic_plan(critic, probe, library, rn_probs, top_k=2).tolist() == [[0, 0], [2, 0]]
    assert critic_plan(critic, probe, library, rn_probs, top_k=1).tolist() == [[2, 0], [2, 0]]


def test_checkpoint_round_trip_and_errors(tmp_path):
    rng = np.random.default_rng(1)
    x, plans, success = synthetic(200, rng)
    critic, _ = train_critic(x, plans, success, CriticConfig(epochs=2, hidden=8, dims=DIMS), progress=False)
    path = save_critic(critic, tmp_path / "c.pt", {"task": "t"})
    again = load_critic(path)
    assert again.meta == {"task": "t"} and again.config == critic.config
    lib = np.array([[0, 0], [1, 1], [2, 0]])
    np.testing.assert_array_equal(critic_plan(again, x[:5], lib), critic_plan(critic, x[:5], lib))
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        load_critic(tmp_path / "missing.pt")
    (tmp_path / "bad.pt").write_bytes(b"not torch")
    with pytest.raises(ValueError, match="bad.pt"):
        load_critic(tmp_path / "bad.pt")
    with pytest.raises(ValueError, match="successes and failures"):
        train_critic(x, plans, np.ones(len(x), bool), CriticConfig(epochs=2, dims=DIMS), progress=False)
    with pytest.raises(ValueError, match="training plans"):
        train_critic(x, plans + 5, success, CriticConfig(epochs=2, dims=DIMS), progress=False)
    with pytest.raises(ValueError, match="top_k"):
        critic_plan(critic, x[:1], lib, [np.ones((1, 3)) / 3, np.ones((1, 2)) / 2], top_k=0)
    with pytest.raises(ValueError, match="dropout"):
        CriticConfig(dropout=1.0)
