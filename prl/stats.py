"""Small statistics for reporting success rates measured in simulation."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval (default 95%) of a success rate ``successes / n``.

    Better than the normal approximation for the small ``n`` and rates near 0 or 1 that simulation
    evaluations give (it never leaves [0, 1]). ValueError names a count outside ``0 <= successes <= n``,
    ``n >= 1``, or a non-positive ``z``."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    if isinstance(successes, bool) or not isinstance(successes, int) or not 0 <= successes <= n:
        raise ValueError(f"successes must be an integer in [0, n={n}], got {successes!r}")
    if not z > 0:
        raise ValueError(f"z must be positive, got {z!r}")
    p = successes / n
    z2 = z * z
    denom = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def format_rate(successes: int, n: int) -> str:
    """``'44/50 = 0.88 (95% CI 0.76-0.94)'``: a success count with its rate and Wilson interval."""
    lo, hi = wilson_interval(successes, n)
    return f"{successes}/{n} = {successes / n:.2f} (95% CI {lo:.2f}-{hi:.2f})"


def importance_weights(prior_logp: Sequence[float], proposal_logp: Sequence[float]) -> np.ndarray:
    """``p / q`` of each kept plan, scaled to mean 1 (self-normalised importance sampling; all 1 for a prior run)."""
    a, b = np.asarray(prior_logp, dtype=np.float64), np.asarray(proposal_logp, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"need one prior and one proposal log-probability per plan, got shapes {a.shape}, {b.shape}")
    if not len(a):
        return a
    if not np.all(np.isfinite(a)) or not np.all(np.isfinite(b)):
        raise ValueError("a kept plan has a log-probability of -inf or nan: the prior or the proposal excludes it")
    log_w = a - b
    w = np.exp(log_w - log_w.max())
    return w / w.mean()


def effective_sample_size(weights: Sequence[float]) -> float:
    """Kish's effective sample size ``(sum w)^2 / sum w^2`` (n for equal weights)."""
    w = np.asarray(weights, dtype=np.float64)
    return float(w.sum() ** 2 / np.sum(w * w)) if len(w) else 0.0
