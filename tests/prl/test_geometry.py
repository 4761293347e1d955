"""Segment distances and box covers (``prl.geometry``), against brute force."""

from __future__ import annotations

import numpy as np
import pytest

from prl.geometry import box_capsules, segment_distance


def _brute(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> float:
    s = np.linspace(0.0, 1.0, 801)[:, None]
    a, b = p1 + s * (q1 - p1), p2 + s * (q2 - p2)
    return float(np.min(np.linalg.norm(a[:, None] - b[None], axis=2)))


@pytest.mark.parametrize("case", ["general", "first a point", "second a point", "both points", "parallel"])
def test_segment_distance_matches_brute_force(case: str) -> None:
    rng = np.random.default_rng(0)
    for _ in range(40):
        p1, q1, p2, q2 = rng.normal(size=(4, 3))
        if case in ("first a point", "both points"):
            q1 = p1
        if case in ("second a point", "both points"):
            q2 = p2
        if case == "parallel":
            q2 = p2 + 1.5 * (q1 - p1)
        d = float(segment_distance(p1, q1, p2, q2))
        brute = _brute(p1, q1, p2, q2)
        assert d <= brute + 1e-9 and brute - d < 5e-3, (case, d, brute)


def test_segment_distance_broadcasts() -> None:
    a = np.zeros((5, 1, 3))
    b = np.zeros((5, 1, 3))
    b[..., 0] = 1.0
    c = np.array([[[0.0, 2.0, 0.0]], [[0.5, 3.0, 0.0]]]).transpose(1, 0, 2)  # (1, 2, 3)
    d = segment_distance(a, b, c, c)
    assert d.shape == (5, 2)
    assert np.allclose(d, [[2.0, 3.0]] * 5)


def test_box_capsules_cover_the_box_and_stay_thin() -> None:
    rng = np.random.default_rng(1)
    for _ in range(30):
        half = rng.uniform(0.01, 0.1, 3)
        caps = box_capsules(half)
        points = rng.uniform(-1.0, 1.0, (500, 3)) * half
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
        for p in (points, corners):
            inside = np.min([segment_distance(p, p, c[:3], c[3:6]) - c[6] for c in caps], axis=0)
            assert np.all(inside <= 1e-12)
        assert np.all(caps[:, 6] <= np.sqrt(2) * np.sort(half)[0] + 1e-12 + np.sort(half)[1] / len(caps))
    flat = box_capsules([0.6, 0.6, 0.01])  # a wide thin plate: many thin capsules, not one fat one
    assert flat[:, 6].max() < 0.02
