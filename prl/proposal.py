"""The synthesis proposal: the distribution plans are drawn from, fixed (the task's prior) or adapted between rounds.

Synthesis keeps the plans that succeed in simulation. Drawn from the task's prior ``p`` (``prl.plb``), the kept
plans are a sample of p(plan | success); on a task whose prior rarely succeeds (the tweeze: 8%) most of the
physics is spent on failures. The adaptive proposal is the cross-entropy method over the per-dimension
categoricals (``prl.cem.update``): synthesis runs in rounds of ``round_attempts`` attempts per shard; between
rounds each dimension moves towards the frequencies of its choices among the round's successful plans,

    q_d <- smoothing * freq_d(successes of the round) + (1 - smoothing) * q_d,   q_d <- max(q_d, floor * p_d), renormalised

starting from q = p. The floor keeps every choice the prior allows at a fixed fraction of its prior probability,
so no choice is ever dropped. Plans are drawn from the defensive mixture ``m = defensive * p + (1 - defensive) * q``
(each plan from the prior with probability ``defensive``, else from q), so that every kept plan's weight
``p / m`` is at most ``1 / defensive``: the per-dimension floor alone bounds a weight only by
((1 + floor) / floor) ** 6, and on the tweeze one demo of 2,000 came to weigh 224x the mean (an effective sample
size of 60; docs/archive/speed.md). A product of per-dimension categoricals cannot hold the joint shape of the successful
plans (the tweeze's pinches and disks mix into plans that are neither), so the adapted draws may also **replay**:
with probability ``replay`` an adapted draw is the plan of one of the earlier rounds' successes, chosen uniformly
among them (a plan that succeeded k times is chosen k times as often), else a draw from q. The mixture is then

    m = defensive * p + (1 - defensive) * ((1 - replay) * q + replay * s),   s(plan) = (successes of plan) / (successes)

which is still exact to evaluate for any plan, and every weight is still at most ``1 / defensive``.

Counted as above, the update and the replays follow the successes *of the proposal*, m(plan) P(success | plan):
each round sharpens the proposal towards the plans that succeed most often (the mode), so its kept plans stand
for fewer and fewer of the prior's, and the weights that restore the prior spread (an effective sample size of
60 of 2,000 tweeze demos; docs/archive/speed.md). With ``weighted`` each success counts by its importance weight
``w = p / m`` (the likelihood-ratio cross-entropy update of rare-event simulation), and the frequencies are taken
over the successes of every round so far:

    q_d <- smoothing * freq_d(successes of rounds <= r, weighted by w) + (1 - smoothing) * q_d,   floored as above
    s(plan) = (sum of w over the successes of plan) / (sum of w over all successes)

The weighted successes are a sample of p(plan | success), the distribution a prior-only run keeps, so q moves
towards that posterior's per-dimension marginals (a fixed point, not a mode) and the replays draw from its
empirical joint, which keeps the kept plans' weights evener. Measured (docs/archive/speed.md): on the tweeze 4.5x the
effective sample size at 1.7x the attempts; on the hammer and the unscrew little change.

The proposal of round r depends only on the attempts of rounds < r, which are themselves fixed by the run seed:
the result does not depend on the number of workers, nor on which shard finished first.

A plan drawn from m and kept is a sample of m(plan) P(success | plan) (up to a constant); its importance weight
``w = p(plan) / m(plan)`` makes the weighted kept plans a sample of p(plan) P(success | plan), the distribution
a prior-only run keeps (self-normalised: only ratios of weights matter). Each attempt records
``proposal_logp`` and ``prior_logp``; whatever reads the demos as "successful plans under the prior" weights
by ``importance_weights`` (the RN's loss and Fig 7, the LN's pre-training).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from prl import cem
from prl.stats import effective_sample_size, importance_weights, wilson_interval

PROPOSALS: tuple[str, ...] = ("prior", "adaptive")
"""Proposal kinds: the task's fixed prior, or the cross-entropy method between rounds (module docstring)."""


@dataclass(frozen=True)
class ProposalConfig:
    """How synthesis draws plans (module docstring)."""

    kind: str = "adaptive"
    """One of ``PROPOSALS``."""
    round_attempts: int = 32
    """Attempts per shard per round; the proposal is updated between rounds (adaptive only)."""
    smoothing: float = 0.5
    """Weight of the round's success frequencies in the update (1: jump to them; 0: never move)."""
    floor: float = 0.2
    """Every choice keeps at least ``floor`` x its prior probability (before renormalising)."""
    defensive: float = 0.2
    """Share of plans drawn from the prior in the adaptive rounds (the defensive mixture: weights <= 1 / defensive);
    0 draws every plan from the adapted proposal (no coin is tossed; weights are bounded by the floor alone)."""
    replay: float = 0.0
    """Share of the adapted draws (those not from the prior) that replay the plan of an earlier round's success
    (module docstring); 0 replays nothing and tosses no coin for it."""
    weighted: bool = False
    """Count each success by its importance weight in the update (over every round so far) and in the replays
    (module docstring), moving the proposal towards the prior's p(plan | success) rather than its mode."""

    def __post_init__(self) -> None:
        if self.kind not in PROPOSALS:
            raise ValueError(f"unknown proposal {self.kind!r}; known: {', '.join(PROPOSALS)}")
        if isinstance(self.round_attempts, bool) or not isinstance(self.round_attempts, int) or self.round_attempts < 1:
            raise ValueError(f"proposal round_attempts must be an integer >= 1, got {self.round_attempts!r}")
        if not _number(self.smoothing) or not 0.0 <= self.smoothing <= 1.0:
            raise ValueError(f"proposal smoothing must be a number in [0, 1], got {self.smoothing!r}")
        if not _number(self.floor) or not 0.0 < self.floor < 1.0:
            raise ValueError(f"proposal floor must be a number in (0, 1), got {self.floor!r}")
        if not _number(self.defensive) or not 0.0 <= self.defensive <= 1.0:
            raise ValueError(f"proposal defensive share must be a number in [0, 1], got {self.defensive!r}")
        if not _number(self.replay) or not 0.0 <= self.replay <= 1.0:
            raise ValueError(f"proposal replay share must be a number in [0, 1], got {self.replay!r}")
        if self.weighted is not True and self.weighted is not False:
            raise ValueError(f"proposal weighted must be true or false, got {self.weighted!r}")


def _number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


Probs = tuple[np.ndarray, ...]


def as_probs(probs: Sequence[Sequence[float]]) -> Probs:
    """Per-dimension probabilities as float arrays (from lists, e.g. a spec sent to a worker)."""
    return tuple(np.asarray(p, dtype=np.float64) for p in probs)


def log_prob(probs: Sequence[np.ndarray], plan: Sequence[int]) -> float:
    """log of the product over dimensions of ``probs[d][plan[d]]`` (``-inf`` for a choice of probability 0)."""
    if len(plan) != len(probs):
        raise ValueError(f"plan {list(plan)} has {len(plan)} dimensions, the distribution {len(probs)}")
    with np.errstate(divide="ignore"):
        return float(sum(np.log(float(p[int(c)])) for p, c in zip(probs, plan)))


def sample_plan(probs: Sequence[np.ndarray], rng: np.random.Generator) -> np.ndarray:
    """One plan, each dimension drawn independently (the same draws as ``PhysicalLawsBank.sample_plan`` when
    ``probs`` is the task's prior: a prior-only run keeps its plans)."""
    return np.array([rng.choice(len(p), p=p) for p in probs], dtype=np.int64)


def sample_mixture(prior: Sequence[np.ndarray], probs: Sequence[np.ndarray], defensive: float,
                   rng: np.random.Generator, replays: np.ndarray | None = None, replay: float = 0.0,
                   replay_weights: np.ndarray | None = None) -> np.ndarray:
    """One plan of the mixture (module docstring): from ``prior`` with probability ``defensive``, else one of
    ``replays`` (earlier successes' plans, rows; chosen uniformly, or in proportion to ``replay_weights``, one per
    row) with probability ``replay``, else from ``probs``. When ``probs`` is
    the prior and there is nothing to replay (round 0) the plan is drawn as a prior-only run draws it (no coin is
    tossed), so round 0 of an adaptive run attempts the very plans of a prior run; no coin is tossed for a share
    of 0 either."""
    replays = _replays(replays, len(prior))
    if not (replay > 0.0 and len(replays)):
        if _same(prior, probs) or defensive <= 0.0:
            return sample_plan(probs, rng)
        return sample_plan(prior if rng.random() < defensive else probs, rng)
    if defensive > 0.0 and rng.random() < defensive:
        return sample_plan(prior, rng)
    if rng.random() < replay:
        if replay_weights is None:
            return replays[int(rng.integers(len(replays)))].copy()
        return replays[int(rng.choice(len(replays), p=_shares(replay_weights, len(replays))))].copy()
    return sample_plan(probs, rng)


def _shares(weights: np.ndarray | Sequence[float], n: int) -> np.ndarray:
    """``weights`` (one per replay, finite, >= 0, not all 0) scaled to sum 1."""
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0) or not w.sum() > 0:
        raise ValueError(f"need one finite weight >= 0 per replay ({n}), not all 0; got {w!r}")
    return w / w.sum()


def _replays(replays: np.ndarray | Sequence[Sequence[int]] | None, n_dims: int) -> np.ndarray:
    return np.asarray(replays if replays is not None else [], dtype=np.int64).reshape(-1, n_dims)


def _same(a: Sequence[np.ndarray], b: Sequence[np.ndarray]) -> bool:
    return len(a) == len(b) and all(np.array_equal(p, q) for p, q in zip(a, b))


def mixture_log_prob(prior: Sequence[np.ndarray], probs: Sequence[np.ndarray], defensive: float,
                     plan: Sequence[int], replays: np.ndarray | None = None, replay: float = 0.0,
                     replay_weights: np.ndarray | None = None) -> float:
    """log of ``m(plan)``, the probability that ``sample_mixture`` with the same arguments draws ``plan``:
    ``defensive * prior + (1 - defensive) * ((1 - replay) * probs + replay * share of plan among replays)``
    (the share of rows equal to ``plan``, or of their ``replay_weights``)."""
    a, b = log_prob(prior, plan), log_prob(probs, plan)
    replays = _replays(replays, len(prior))
    if not (replay > 0.0 and len(replays)):
        if defensive >= 1.0 or _same(prior, probs):  # round 0: exactly the prior's
            return a
        if defensive <= 0.0:
            return b
        return float(np.logaddexp(np.log(defensive) + a, np.log1p(-defensive) + b))
    same = np.all(replays == np.asarray(plan, dtype=np.int64), axis=1)
    share = float(np.mean(same)) if replay_weights is None else float(_shares(replay_weights, len(replays))[same].sum())
    terms = [np.log(defensive) + a if defensive > 0.0 else -np.inf]
    if defensive < 1.0:
        terms.append(np.log1p(-defensive) + np.log1p(-replay) + b if replay < 1.0 else -np.inf)
        terms.append(np.log1p(-defensive) + np.log(replay) + np.log(share) if share > 0.0 else -np.inf)
    return float(np.logaddexp.reduce(terms))


def adapt(current: Sequence[np.ndarray], prior: Sequence[np.ndarray], successes: np.ndarray,
          cfg: ProposalConfig, weights: Sequence[float] | None = None) -> Probs:
    """The next round's proposal from this round's (``current``) and the successful plans it moves towards
    (``weights``: one per plan, or None to count each once; module docstring); unchanged when there is no success
    or the proposal is the prior."""
    successes = np.asarray(successes, dtype=np.int64).reshape(-1, len(prior))
    if cfg.kind == "prior":
        return as_probs(prior)
    if not len(successes):
        return as_probs(current)
    return tuple(cem.update(list(current), successes, smoothing=cfg.smoothing, reference=list(prior), floor=cfg.floor,
                            weights=weights))


def round_proposals(prior: Sequence[np.ndarray], successes_by_round: Sequence[np.ndarray],
                    cfg: ProposalConfig, weights_by_round: Sequence[Sequence[float]] | None = None) -> list[Probs]:
    """The proposal of every round: round 0's is the prior, round r + 1's ``adapt``s round r's on round r's
    successes, or with ``cfg.weighted`` on the successes of rounds <= r weighted by ``weights_by_round`` (their
    importance weights, one per plan of ``successes_by_round``). Returns ``len(successes_by_round) + 1`` proposals
    (the last for the round about to run)."""
    if cfg.weighted and len(successes_by_round) and (weights_by_round is None
                                                     or len(weights_by_round) != len(successes_by_round)):
        raise ValueError("a weighted proposal needs the importance weights of every round's successes")
    out = [as_probs(prior)]
    for k, plans in enumerate(successes_by_round):
        if cfg.weighted and len(plans):  # a round without success leaves the proposal as it was (``adapt``)
            so_far = np.concatenate([np.asarray(p, dtype=np.int64).reshape(-1, len(prior))
                                     for p in successes_by_round[:k + 1]])
            w = np.concatenate([np.asarray(x, dtype=np.float64).reshape(-1) for x in weights_by_round[:k + 1]])
            out.append(adapt(out[-1], prior, so_far, cfg, w))
        else:
            out.append(adapt(out[-1], prior, plans, cfg))
    return out


def weighted_choice_freqs(plans: np.ndarray, sizes: Sequence[int], weights: Sequence[float] | None = None) -> Probs:
    """Per dimension, the (weighted) frequency of each choice among ``plans`` (rows)."""
    plans = np.asarray(plans, dtype=np.int64).reshape(-1, len(sizes))
    w = np.ones(len(plans)) if weights is None else np.asarray(weights, dtype=np.float64)
    out = []
    for d, m in enumerate(sizes):
        f = np.bincount(plans[:, d], weights=w, minlength=int(m)).astype(np.float64)
        out.append(f / f.sum() if f.sum() else f)
    return tuple(out)


def entropies(plans: np.ndarray, sizes: Sequence[int]) -> np.ndarray:
    """Per dimension, the entropy (nats) of the choices' frequencies among ``plans``."""
    out = []
    for f in weighted_choice_freqs(plans, sizes):
        nz = f[f > 0]
        out.append(max(0.0, float(-(nz * np.log(nz)).sum())))
    return np.asarray(out)


def round_table(rows: Sequence[Mapping[str, Any]], sizes: Sequence[int]) -> list[dict[str, Any]]:
    """The record of one task's synthesis per round, from its attempt-log rows (any shard order): the round's
    attempts, successes and yield with its 95% Wilson interval, and over the demos kept up to the round's end
    their number, distinct plans, per-dimension entropy (nats) and effective sample size under the weights."""
    out = []
    rounds = sorted({int(r.get("round", 0)) for r in rows})
    for k in rounds:
        now = [r for r in rows if int(r.get("round", 0)) == k]
        kept = [r for r in rows if int(r.get("round", 0)) <= k and r["success"]]
        n, ok = len(now), sum(bool(r["success"]) for r in now)
        lo, hi = wilson_interval(ok, n) if n else (0.0, 0.0)
        plans = np.array([r["plan"] for r in kept], dtype=np.int64).reshape(-1, len(sizes))
        logged = kept and all("proposal_logp" in r and "prior_logp" in r for r in kept)
        weights = importance_weights([r["prior_logp"] for r in kept], [r["proposal_logp"] for r in kept]) \
            if logged else np.ones(len(kept))
        out.append({"round": k, "attempts": n, "successes": ok, "yield": ok / n if n else 0.0,
                    "yield_ci95": [lo, hi], "kept": len(kept),
                    "distinct_plans": len({tuple(p) for p in plans.tolist()}),
                    "entropy": [round(float(e), 4) for e in entropies(plans, sizes)],
                    "ess": effective_sample_size(weights)})
    return out
