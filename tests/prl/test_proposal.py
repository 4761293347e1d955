"""The synthesis proposal: updates computed by hand, the floor, the weights that restore the prior."""

from __future__ import annotations

import numpy as np
import pytest

from prl.proposal import (
    ProposalConfig,
    adapt,
    log_prob,
    mixture_log_prob,
    round_proposals,
    round_table,
    sample_mixture,
    sample_plan,
    weighted_choice_freqs,
)
from prl.stats import effective_sample_size, importance_weights

PRIOR = (np.array([0.5, 0.5]), np.array([0.2, 0.3, 0.5]))


def test_update_by_hand() -> None:
    """Two successes [1, 2] and [1, 0]; smoothing 0.5, floor 0.2:
    dim 0: 0.5 * [0, 1] + 0.5 * [0.5, 0.5] = [0.25, 0.75]; floors 0.1 -> unchanged.
    dim 1: 0.5 * [0.5, 0, 0.5] + 0.5 * [0.2, 0.3, 0.5] = [0.35, 0.15, 0.5]; floors [0.04, 0.06, 0.1] -> unchanged."""
    cfg = ProposalConfig(smoothing=0.5, floor=0.2)
    q = adapt(PRIOR, PRIOR, np.array([[1, 2], [1, 0]]), cfg)
    np.testing.assert_allclose(q[0], [0.25, 0.75])
    np.testing.assert_allclose(q[1], [0.35, 0.15, 0.5])
    # a second round with one success [1, 2]: dim 1 0.5 * [0, 0, 1] + 0.5 * [0.35, 0.15, 0.5] = [0.175, 0.075, 0.75]
    q2 = adapt(q, PRIOR, np.array([[1, 2]]), cfg)
    np.testing.assert_allclose(q2[1], [0.175, 0.075, 0.75])
    np.testing.assert_allclose(q2[0], [0.125, 0.875])


def test_floor_holds_and_no_success_keeps_the_proposal() -> None:
    """smoothing 1 jumps to the successes' frequencies [0, 0, 1]; the floor 0.2 x prior lifts 0 -> 0.04 and 0.06,
    renormalised by 1.1: [0.04, 0.06, 1] / 1.1."""
    cfg = ProposalConfig(smoothing=1.0, floor=0.2)
    q = adapt(PRIOR, PRIOR, np.array([[0, 2]] * 5), cfg)
    np.testing.assert_allclose(q[1], np.array([0.04, 0.06, 1.0]) / 1.1)
    for _ in range(20):  # however long it adapts, every choice keeps >= floor x prior / (1 + floor)
        q = adapt(q, PRIOR, np.array([[0, 2]] * 5), cfg)
    for p, pri in zip(q, PRIOR):
        assert np.all(p >= 0.2 * pri / 1.2 - 1e-12)
    assert adapt(q, PRIOR, np.zeros((0, 2)), cfg) == q  # a round without success
    prior_cfg = ProposalConfig(kind="prior")
    assert all(np.array_equal(a, b) for a, b in zip(adapt(q, PRIOR, np.array([[0, 2]]), prior_cfg), PRIOR))


def test_round_proposals_chain() -> None:
    cfg = ProposalConfig(smoothing=0.5, floor=0.2)
    rounds = round_proposals(PRIOR, [np.array([[1, 2], [1, 0]]), np.array([[1, 2]])], cfg)
    assert len(rounds) == 3
    np.testing.assert_allclose(rounds[0][1], PRIOR[1])
    np.testing.assert_allclose(rounds[2][1], [0.175, 0.075, 0.75])


def test_weighted_rounds_by_hand() -> None:
    """Weighted (smoothing 0.5, floor 0.2): round 0 kept [1, 2] (weight 3) and [1, 0] (weight 1):
    dim 1: freq [1/4, 0, 3/4] -> 0.5 * [0.25, 0, 0.75] + 0.5 * [0.2, 0.3, 0.5] = [0.225, 0.15, 0.625].
    Round 1 kept [0, 2] (weight 2); the frequencies are over both rounds' successes (weights 3, 1, 2):
    dim 0: [2/6, 4/6] -> 0.5 * [1/3, 2/3] + 0.5 * [0.25, 0.75] = [0.291667, 0.708333];
    dim 1: [1/6, 0, 5/6] -> 0.5 * [1/6, 0, 5/6] + 0.5 * [0.225, 0.15, 0.625] = [0.195833, 0.075, 0.729167]
    (floors [0.04, 0.06, 0.1]: unchanged)."""
    cfg = ProposalConfig(smoothing=0.5, floor=0.2, weighted=True)
    rounds = round_proposals(PRIOR, [np.array([[1, 2], [1, 0]]), np.array([[0, 2]])], cfg, [[3.0, 1.0], [2.0]])
    np.testing.assert_allclose(rounds[1][1], [0.225, 0.15, 0.625])
    np.testing.assert_allclose(rounds[2][0], [0.291667, 0.708333], atol=1e-6)
    np.testing.assert_allclose(rounds[2][1], [0.195833, 0.075, 0.729167], atol=1e-6)
    with pytest.raises(ValueError, match="needs the importance weights of every round's successes"):
        round_proposals(PRIOR, [np.array([[1, 2]])], cfg)


def test_weighted_replays_by_hand_and_by_sampling() -> None:
    """Replays [0, 1], [1, 2], [0, 1] with weights 1, 2, 1: plan [0, 1] holds 2 / 4 of the replay share (uniformly it
    would be 2 / 3). m([0, 1]) = 0.1 * p + 0.9 * (0.5 * q + 0.5 * 0.5) with p = 0.5 * 0.3 = 0.15 and
    q = 0.8 * 0.1 = 0.08; and the draws of ``sample_mixture`` follow ``mixture_log_prob``."""
    q = (np.array([0.8, 0.2]), np.array([0.6, 0.1, 0.3]))
    replays, weights = np.array([[0, 1], [1, 2], [0, 1]]), np.array([1.0, 2.0, 1.0])
    want = 0.1 * 0.15 + 0.9 * (0.5 * 0.08 + 0.5 * 0.5)
    assert np.exp(mixture_log_prob(PRIOR, q, 0.1, [0, 1], replays, 0.5, weights)) == pytest.approx(want)
    uniform = 0.1 * 0.15 + 0.9 * (0.5 * 0.08 + 0.5 * 2 / 3)
    assert np.exp(mixture_log_prob(PRIOR, q, 0.1, [0, 1], replays, 0.5)) == pytest.approx(uniform)
    rng = np.random.default_rng(0)
    draws = np.array([sample_mixture(PRIOR, q, 0.1, rng, replays, 0.5, weights) for _ in range(20000)])
    for plan in ([0, 1], [1, 2], [0, 0]):
        got = np.mean(np.all(draws == plan, axis=1))
        assert got == pytest.approx(np.exp(mixture_log_prob(PRIOR, q, 0.1, plan, replays, 0.5, weights)), abs=0.01)
    with pytest.raises(ValueError, match="one finite weight >= 0 per replay"):
        sample_mixture(PRIOR, q, 0.0, rng, replays, 1.0, np.array([1.0, 2.0]))


def test_sampling_from_the_prior_matches_the_catalogue() -> None:
    """The prior proposal draws the plans the catalogue's own sampler draws (a prior run keeps its demos)."""
    from prl.plb import load_plb

    plb = load_plb()
    for task in ("hammer", "tweeze"):
        for seed in range(5):
            a = plb.sample_plan(task, np.random.default_rng(seed))
            b = sample_plan(plb.prior(task), np.random.default_rng(seed))
            assert a.tolist() == b.tolist()


def test_log_prob_and_weights_by_hand() -> None:
    assert log_prob(PRIOR, [1, 2]) == pytest.approx(np.log(0.5 * 0.5))
    assert log_prob((np.array([1.0, 0.0]),), [1]) == -np.inf
    w = importance_weights([np.log(0.2), np.log(0.1)], [np.log(0.1), np.log(0.2)])  # ratios 2 and 0.5 -> mean 1.25
    np.testing.assert_allclose(w, [2 / 1.25, 0.5 / 1.25])
    assert effective_sample_size([1, 1, 1, 1]) == pytest.approx(4.0)
    assert effective_sample_size([1, 0, 0, 0]) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="-inf or nan"):
        importance_weights([0.0, -np.inf], [0.0, 0.0])


def test_weights_restore_the_prior_on_a_bandit() -> None:
    """A synthetic bandit whose success probability is known per choice: plans kept under the adaptive proposal,
    weighted prior / proposal, have the per-dimension choice frequencies of plans kept under the prior
    (p(c) P(success | c) / Z), though the unweighted kept plans do not."""
    prior = (np.array([0.6, 0.3, 0.1]), np.array([0.5, 0.5]))
    p_success = (np.array([0.05, 0.2, 0.9]), np.array([0.3, 0.6]))  # success needs both dims to "pass"
    want0 = prior[0] * p_success[0] / np.sum(prior[0] * p_success[0])
    want1 = prior[1] * p_success[1] / np.sum(prior[1] * p_success[1])
    cfg = ProposalConfig(smoothing=0.7, floor=0.2)
    rng = np.random.default_rng(0)
    q = tuple(np.asarray(p) for p in prior)
    kept, prior_lp, prop_lp = [], [], []
    for _ in range(20):
        successes = []
        for _ in range(2000):
            plan = sample_plan(q, rng)
            if rng.random() < p_success[0][plan[0]] * p_success[1][plan[1]]:
                successes.append(plan)
                kept.append(plan)
                prior_lp.append(log_prob(prior, plan))
                prop_lp.append(log_prob(q, plan))
        q = adapt(q, prior, np.array(successes).reshape(-1, 2), cfg)
    kept = np.array(kept)
    raw = weighted_choice_freqs(kept, (3, 2))
    weighted = weighted_choice_freqs(kept, (3, 2), importance_weights(prior_lp, prop_lp))
    np.testing.assert_allclose(weighted[0], want0, atol=0.03)
    np.testing.assert_allclose(weighted[1], want1, atol=0.03)
    assert abs(raw[0][2] - want0[2]) > 0.1  # the proposal moved onto choice 2: unweighted, it is over-represented


BANDIT_PRIOR = (np.array([0.6, 0.3, 0.1]), np.array([0.7, 0.3]))


def _bandit_run(cfg: ProposalConfig, p_success: np.ndarray, rounds: int = 12,
                per_round: int = 400) -> tuple[np.ndarray, np.ndarray, float]:
    """Synthesis on a bandit whose success probability ``p_success[a0, a1]`` is known per plan (the prior
    ``BANDIT_PRIOR``), with ``cfg``'s rounds, mixture and replays: the kept plans, their importance weights and the
    yield."""
    prior = BANDIT_PRIOR
    rng = np.random.default_rng(1)
    kept, prior_lp, prop_lp, by_round = [], [], [], []
    attempts = 0
    for r in range(rounds):
        split = np.cumsum([len(b) for b in by_round])[:-1]
        weights = np.split(importance_weights(prior_lp, prop_lp), split) if cfg.weighted and by_round else None
        q = round_proposals(prior, by_round, cfg, weights)[r]
        replays = np.concatenate(by_round) if by_round else np.zeros((0, 2), np.int64)
        rw = np.concatenate(weights) if weights else None
        won = []
        for _ in range(per_round):
            plan = sample_mixture(prior, q, cfg.defensive, rng, replays, cfg.replay, rw)
            attempts += 1
            if rng.random() < p_success[plan[0], plan[1]]:
                won.append(plan)
                kept.append(plan)
                prior_lp.append(log_prob(prior, plan))
                prop_lp.append(mixture_log_prob(prior, q, cfg.defensive, plan, replays, cfg.replay, rw))
        by_round.append(np.array(won, dtype=np.int64).reshape(-1, 2))
    return np.array(kept), importance_weights(prior_lp, prop_lp), len(kept) / attempts


@pytest.mark.parametrize(("p_success", "ess_ratio"), [
    (np.array([[0.02, 0.05], [0.02, 0.1], [0.05, 0.9]]), 3.0),  # one reliable plan, (2, 1), many rarely succeed
    (np.array([[0.01, 0.0], [0.7, 0.05], [0.0, 0.9]]), 1.1),  # two reliable plans whose choices interact
])
def test_weighted_proposal_keeps_the_priors_successes_with_evener_weights_on_a_bandit(p_success: np.ndarray,
                                                                                     ess_ratio: float) -> None:
    """Both updates with replays (smoothing 0.5, floor 0.2, defensive 0.1, replay 0.8) raise the yield well above
    the prior's. Counted plainly the rounds sharpen onto the likeliest success and the weights spread; counted by
    weight the proposal follows the prior's successes: the effective sample size of its kept plans is higher
    (3x with many rarely-successful plans in the prior's successes, at some cost in yield), and its weighted kept
    plans hold every plan within 0.04 of the share a prior run keeps it, p(plan) P(success | plan) / Z."""
    joint = np.outer(*BANDIT_PRIOR) * p_success
    posterior, prior_yield = joint / joint.sum(), float(joint.sum())
    ess = {}
    for weighted in (False, True):
        cfg = ProposalConfig(smoothing=0.5, floor=0.2, defensive=0.1, replay=0.8, weighted=weighted)
        kept, w, yield_ = _bandit_run(cfg, p_success)
        assert yield_ > 2.5 * prior_yield, (weighted, yield_)
        ess[weighted] = effective_sample_size(w) / len(w)
        if weighted:
            shares = [[np.sum(w * np.all(kept == [i, j], axis=1)) / np.sum(w) for j in range(2)] for i in range(3)]
            np.testing.assert_allclose(shares, posterior, atol=0.04)
    assert ess[True] > ess_ratio * ess[False], ess


def test_bad_settings_are_clear_errors() -> None:
    with pytest.raises(ValueError, match="unknown proposal 'cem'; known: prior, adaptive"):
        ProposalConfig(kind="cem")
    with pytest.raises(ValueError, match="round_attempts must be an integer >= 1, got 0"):
        ProposalConfig(round_attempts=0)
    with pytest.raises(ValueError, match="floor must be a number in \\(0, 1\\), got 'x'"):
        ProposalConfig(floor="x")
    with pytest.raises(ValueError, match="weighted must be true or false, got 'yes'"):
        ProposalConfig(weighted="yes")


def test_round_table_by_hand() -> None:
    rows = [{"round": 0, "plan": [0, 1], "success": True, "prior_logp": 0.0, "proposal_logp": 0.0},
            {"round": 0, "plan": [1, 1], "success": False, "prior_logp": 0.0, "proposal_logp": 0.0},
            {"round": 1, "plan": [0, 1], "success": True, "prior_logp": np.log(0.5), "proposal_logp": np.log(0.25)},
            {"round": 1, "plan": [1, 0], "success": True, "prior_logp": np.log(0.5), "proposal_logp": np.log(0.5)}]
    table = round_table(rows, (2, 2))
    assert [(t["round"], t["attempts"], t["successes"], t["kept"], t["distinct_plans"]) for t in table] == \
        [(0, 2, 1, 1, 1), (1, 2, 2, 3, 2)]
    assert table[0]["yield"] == 0.5 and table[1]["yield"] == 1.0
    # round 1's kept weights 1, 2, 1 -> ESS 16 / 6
    assert table[1]["ess"] == pytest.approx(16 / 6)
    # dim 0 among kept [0, 0, 1]: entropy -(2/3 ln 2/3 + 1/3 ln 1/3)
    assert table[1]["entropy"][0] == pytest.approx(-(2 / 3 * np.log(2 / 3) + 1 / 3 * np.log(1 / 3)), abs=1e-4)


def test_consumers_weight_the_demos() -> None:
    """The RN's cross-entropy and Fig 7's means take the demos' weights: weight 0 drops a sample, and the means
    are computed by hand."""
    import torch

    from prl.rn import RNConfig, rn_loss
    from prl.rn_decode import key_dimensions

    cfg = RNConfig(dims=(2, 3))
    logits = [torch.tensor([[2.0, 0.0], [0.0, 1.0]]), torch.tensor([[0.0, 1.0, 2.0], [1.0, 0.0, 0.0]])]
    y = torch.tensor([[0, 2], [1, 0]])
    both = rn_loss(logits, y, cfg)["ce"]
    first = rn_loss([lg[:1] for lg in logits], y[:1], cfg)["ce"]
    assert float(rn_loss(logits, y, cfg, torch.tensor([1.0, 0.0]))["ce"]) == pytest.approx(float(first))
    assert float(rn_loss(logits, y, cfg, torch.tensor([1.0, 1.0]))["ce"]) == pytest.approx(float(both))
    probs = [np.array([[0.9, 0.1], [0.3, 0.7]])]
    s = key_dimensions(probs, weights=[3.0, 1.0])[0]
    np.testing.assert_allclose(s.mean_probs, [(3 * 0.9 + 0.3) / 4, (3 * 0.1 + 0.7) / 4])
    assert s.mean_max_prob == pytest.approx((3 * 0.9 + 0.7) / 4)


def test_demo_weights_per_task() -> None:
    """Weights are prior / proposal, mean 1 within each task; episodes without log-probabilities weigh 1."""
    from prl.features import demo_weights

    scenes = [{"task": "hammer", "prior_logp": np.log(0.2), "proposal_logp": np.log(0.1)},
              {"task": "hammer", "prior_logp": np.log(0.1), "proposal_logp": np.log(0.2)},
              {"task": "sweep"}, {"task": "sweep", "prior_logp": None, "proposal_logp": None}]
    np.testing.assert_allclose(demo_weights(scenes), [2 / 1.25, 0.5 / 1.25, 1.0, 1.0])


def test_a_bad_proposal_flag_is_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    from flows.full_pipeline import main
    from prl.config import ConfigError, make_config

    assert main(["--proposal", "cem"]) == 2
    assert "unknown proposal 'cem'; known: prior, adaptive" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="proposal floor must be a number in \\(0, 1\\), got 1.5"):
        make_config("quick", proposal_floor=1.5)
    assert make_config("paper").proposal_config() == ProposalConfig()  # adaptive by default in both profiles
    assert make_config("quick", proposal="prior").proposal_config().kind == "prior"


def test_the_defensive_mixture_bounds_every_weight() -> None:
    """m = 0.2 p + 0.8 q: for plan [1, 2], p = 0.5 * 0.5 = 0.25 and q = 0.75 * 0.5 = 0.375, so m = 0.05 + 0.3 = 0.35;
    on the bandit, every raw weight p / m stays <= 1 / 0.2 and the weighted kept plans still restore the prior's."""
    from prl.proposal import mixture_log_prob, sample_mixture

    q = (np.array([0.25, 0.75]), np.array([0.35, 0.15, 0.5]))
    assert mixture_log_prob(PRIOR, q, 0.2, [1, 2]) == pytest.approx(np.log(0.35))
    assert mixture_log_prob(PRIOR, q, 1.0, [1, 2]) == pytest.approx(np.log(0.25))
    prior = (np.array([0.6, 0.3, 0.1]), np.array([0.5, 0.5]))
    p_success = (np.array([0.05, 0.2, 0.9]), np.array([0.3, 0.6]))
    want0 = prior[0] * p_success[0] / np.sum(prior[0] * p_success[0])
    cfg = ProposalConfig(smoothing=0.7, floor=0.2, defensive=0.2)
    rng = np.random.default_rng(1)
    q, kept, prior_lp, mix_lp = prior, [], [], []
    for _ in range(20):
        successes = []
        for _ in range(2000):
            plan = sample_mixture(prior, q, cfg.defensive, rng)
            if rng.random() < p_success[0][plan[0]] * p_success[1][plan[1]]:
                successes.append(plan)
                kept.append(plan)
                prior_lp.append(log_prob(prior, plan))
                mix_lp.append(mixture_log_prob(prior, q, cfg.defensive, plan))
        q = adapt(q, prior, np.array(successes).reshape(-1, 2), cfg)
    raw = np.exp(np.array(prior_lp) - np.array(mix_lp))
    assert raw.max() <= 1 / cfg.defensive + 1e-9
    w = importance_weights(prior_lp, mix_lp)
    np.testing.assert_allclose(weighted_choice_freqs(np.array(kept), (3, 2), w)[0], want0, atol=0.03)
    assert effective_sample_size(w) > 0.12 * len(kept)  # 16% here; the floor alone kept 4-5% on this bandit


def test_round_0_of_the_mixture_draws_the_prior_runs_plans() -> None:
    from prl.proposal import sample_mixture

    for seed in range(5):
        assert sample_mixture(PRIOR, PRIOR, 0.2, np.random.default_rng(seed)).tolist() == \
            sample_plan(PRIOR, np.random.default_rng(seed)).tolist()


def test_defensive_zero_draws_from_the_proposal_alone() -> None:
    """With no prior share no coin is tossed: the plan and its log-probability are the adapted proposal's, so a
    run with ``--proposal-defensive 0`` attempts the plans the adaptive proposal drew before the mixture existed."""
    from prl.proposal import mixture_log_prob, sample_mixture

    q = (np.array([0.25, 0.75]), np.array([0.35, 0.15, 0.5]))
    for seed in range(5):
        assert sample_mixture(PRIOR, q, 0.0, np.random.default_rng(seed)).tolist() == \
            sample_plan(q, np.random.default_rng(seed)).tolist()
    assert mixture_log_prob(PRIOR, q, 0.0, [1, 2]) == pytest.approx(np.log(0.75 * 0.5))
    assert ProposalConfig(defensive=0.0).defensive == 0.0
    with pytest.raises(ValueError, match="defensive share must be a number in \\[0, 1\\], got -0.1"):
        ProposalConfig(defensive=-0.1)


def test_the_synthesis_directory_names_the_defensive_share_unless_it_is_zero(tmp_path) -> None:
    from flows.synthesize import synthesis_dir
    from prl.config import make_config

    names = [synthesis_dir(make_config(output_dir=str(tmp_path), proposal_defensive=d)).name for d in (0.2, 0.0)]
    assert names == ["seed0-shards2-frames750-adaptive-r32-s0.5-f0.2-d0.2", "seed0-shards2-frames750-adaptive-r32-s0.5-f0.2"]


def test_the_replay_mixture_by_hand_and_its_draws() -> None:
    """m = d p + (1 - d) ((1 - x) q + x s) with d = 0.2, x = 0.5 and the replays [1, 2] (twice) and [0, 0]: for
    [1, 2], p = 0.25, q = 0.375 and s = 2/3, so m = 0.05 + 0.8 (0.1875 + 0.3333) = 0.46667; for [0, 1], never a
    success, s = 0: m = 0.2 * 0.15 + 0.4 * 0.25 * 0.15 = 0.045. Drawn 40,000 times, each plan's frequency is m."""
    from prl.proposal import mixture_log_prob, sample_mixture

    q = (np.array([0.25, 0.75]), np.array([0.35, 0.15, 0.5]))
    replays = np.array([[1, 2], [0, 0], [1, 2]])
    assert mixture_log_prob(PRIOR, q, 0.2, [1, 2], replays, 0.5) == pytest.approx(np.log(0.05 + 0.8 * (0.1875 + 1 / 3)))
    assert mixture_log_prob(PRIOR, q, 0.2, [0, 1], replays, 0.5) == pytest.approx(np.log(0.2 * 0.15 + 0.4 * 0.25 * 0.15))
    assert mixture_log_prob(PRIOR, q, 0.0, [0, 0], replays, 1.0) == pytest.approx(np.log(1 / 3))  # replays alone
    rng = np.random.default_rng(3)
    draws = np.array([sample_mixture(PRIOR, q, 0.2, rng, replays, 0.5) for _ in range(40_000)])
    for plan in ([1, 2], [0, 1], [0, 0]):
        want = np.exp(mixture_log_prob(PRIOR, q, 0.2, plan, replays, 0.5))
        assert np.mean(np.all(draws == plan, axis=1)) == pytest.approx(want, abs=0.01)
    # nothing to replay, or a share of 0: the draws and the log-probability of the mixture without replays
    for seed in range(5):
        for reps, share in ((replays, 0.0), (None, 0.5)):
            assert sample_mixture(PRIOR, q, 0.2, np.random.default_rng(seed), reps, share).tolist() == \
                sample_mixture(PRIOR, q, 0.2, np.random.default_rng(seed)).tolist()
    assert mixture_log_prob(PRIOR, q, 0.2, [1, 2], replays, 0.0) == pytest.approx(np.log(0.35))
    with pytest.raises(ValueError, match="replay share must be a number in \\[0, 1\\], got 1.5"):
        ProposalConfig(replay=1.5)


def test_replays_keep_the_weights_bounded_and_restore_the_prior() -> None:
    """The bandit of ``test_the_defensive_mixture_bounds_every_weight`` with half the adapted draws replaying the
    earlier rounds' successes: more successes per attempt, every raw weight still <= 1 / 0.2, and the weighted
    kept plans still have the prior's choice frequencies."""
    from prl.proposal import mixture_log_prob, sample_mixture

    prior = (np.array([0.6, 0.3, 0.1]), np.array([0.5, 0.5]))
    p_success = (np.array([0.05, 0.2, 0.9]), np.array([0.3, 0.6]))
    want0 = prior[0] * p_success[0] / np.sum(prior[0] * p_success[0])
    cfg = ProposalConfig(smoothing=0.7, floor=0.2, defensive=0.2, replay=0.5)

    def run(replay: float) -> tuple[float, np.ndarray, list, list]:
        rng = np.random.default_rng(1)
        q, kept, prior_lp, mix_lp, successes_before = prior, [], [], [], np.zeros((0, 2), np.int64)
        attempts = 0
        for _ in range(20):
            successes = []
            for _ in range(2000):
                plan = sample_mixture(prior, q, cfg.defensive, rng, successes_before, replay)
                attempts += 1
                if rng.random() < p_success[0][plan[0]] * p_success[1][plan[1]]:
                    successes.append(plan)
                    kept.append(plan)
                    prior_lp.append(log_prob(prior, plan))
                    mix_lp.append(mixture_log_prob(prior, q, cfg.defensive, plan, successes_before, replay))
            q = adapt(q, prior, np.array(successes).reshape(-1, 2), cfg)
            successes_before = np.concatenate([successes_before, np.array(successes).reshape(-1, 2)])
        return len(kept) / attempts, np.array(kept), prior_lp, mix_lp

    plain_yield = run(0.0)[0]
    yield_, kept, prior_lp, mix_lp = run(cfg.replay)
    assert yield_ > plain_yield  # replaying the best plans' successes pays on this bandit
    assert np.exp(np.array(prior_lp) - np.array(mix_lp)).max() <= 1 / cfg.defensive + 1e-9
    w = importance_weights(prior_lp, mix_lp)
    np.testing.assert_allclose(weighted_choice_freqs(kept, (3, 2), w)[0], want0, atol=0.03)


def test_the_synthesis_directory_names_the_replay_share_the_weighting_and_the_replay_check(tmp_path) -> None:
    from flows.synthesize import synthesis_dir
    from prl.config import ConfigError, make_config

    names = [synthesis_dir(make_config(output_dir=str(tmp_path), proposal_replay=x)).name for x in (0.5, 0.0)]
    assert names == ["seed0-shards2-frames750-adaptive-r32-s0.5-f0.2-d0.2-x0.5",
                     "seed0-shards2-frames750-adaptive-r32-s0.5-f0.2-d0.2"]
    weighted = synthesis_dir(make_config(output_dir=str(tmp_path), proposal_replay=0.5, proposal_weighted=True))
    assert weighted.name == "seed0-shards2-frames750-adaptive-r32-s0.5-f0.2-d0.2-x0.5-w"
    checked = synthesis_dir(make_config(output_dir=str(tmp_path), proposal_replay=0.0, replay_check=True))
    assert checked.name == "seed0-shards2-frames750-adaptive-r32-s0.5-f0.2-d0.2-replayed"  # other attempts' demos
    with pytest.raises(ConfigError, match="replay share must be a number in \\[0, 1\\], got -1"):
        make_config(output_dir=str(tmp_path), proposal_replay=-1)
