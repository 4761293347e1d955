"""Small statistics for reporting success rates measured in simulation."""

from __future__ import annotations

import math


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
