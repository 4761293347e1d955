"""Wilson intervals of success rates, against values computed by hand."""

from __future__ import annotations

import pytest

from prl.stats import format_rate, wilson_interval


def test_wilson_interval_hand_computed() -> None:
    # 89/100: z^2/n = .038416; centre (.89 + .019208) / 1.038416 = .87557;
    # half 1.96 * sqrt(.89 * .11 / 100 + 3.8416 / 40000) / 1.038416 = .061887
    lo, hi = wilson_interval(89, 100)
    assert lo == pytest.approx(0.87557 - 0.061887, abs=1e-5)
    assert hi == pytest.approx(0.87557 + 0.061887, abs=1e-5)
    # 0/10: centre = half = .19208 / 1.38416 = .13877, so the interval is [0, .27754]
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.27754, abs=1e-5)
    lo, hi = wilson_interval(10, 10)
    assert hi == 1.0 and lo == pytest.approx(1 - 0.27754, abs=1e-5)
    # 44/50: (.762, .944)
    assert format_rate(44, 50) == "44/50 = 0.88 (95% CI 0.76-0.94)"


@pytest.mark.parametrize(("args", "match"), [
    ((3, 0), "n must be an integer >= 1, got 0"),
    ((11, 10), r"successes must be an integer in \[0, n=10\], got 11"),
    ((-1, 10), r"got -1"),
    ((2.0, 10), r"got 2.0"),
    ((1, 10, 0.0), "z must be positive, got 0.0"),
])
def test_wilson_interval_rejects_bad_counts(args: tuple, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        wilson_interval(*args)
