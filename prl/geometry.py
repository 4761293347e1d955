"""Elementary rotations (radians), shared by the IK, the executor and the task scenes."""

from __future__ import annotations

import numpy as np


def rot_x(a: float) -> np.ndarray:
    """Rotation matrix (3, 3) about X by ``a`` radians."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """Rotation matrix (3, 3) about Y by ``a`` radians."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    """Rotation matrix (3, 3) about Z by ``a`` radians."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Shortest distance between the segments [p1, q1] and [p2, q2] (arrays (..., 3), broadcast against each
    other; a segment may have zero length). The closest-point method of Ericson, *Real-Time Collision
    Detection* (2005), sec. 5.1.9, vectorised: the distance between two capsules is this minus their radii."""
    p1, q1, p2, q2 = (np.asarray(x, dtype=np.float64) for x in (p1, q1, p2, q2))
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = np.einsum("...i,...i->...", d1, d1), np.einsum("...i,...i->...", d2, d2)
    b, c, f = (np.einsum("...i,...i->...", u, v) for u, v in ((d1, d2), (d1, r), (d2, r)))
    eps = 1e-18
    a_ok, e_ok = a > eps, e > eps
    safe_a, safe_e = np.where(a_ok, a, 1.0), np.where(e_ok, e, 1.0)
    denom = a * e - b * b
    s = np.where(denom > eps, np.clip((b * f - c * e) / np.where(denom > eps, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / safe_e
    s = np.where(t < 0.0, np.clip(-c / safe_a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / safe_a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    # degenerate segments: a point against a segment, or two points
    s = np.where(e_ok, s, np.clip(-c / safe_a, 0.0, 1.0))
    t = np.where(e_ok, t, 0.0)
    s = np.where(a_ok, s, 0.0)
    t = np.where(a_ok, t, np.where(e_ok, np.clip(f / safe_e, 0.0, 1.0), 0.0))
    gap = (p1 + d1 * s[..., None]) - (p2 + d2 * t[..., None])
    return np.sqrt(np.einsum("...i,...i->...", gap, gap))


def box_capsules(half: np.ndarray) -> np.ndarray:
    """Capsules that together contain the box of half extents ``half`` (3,) centred at the origin, axis-aligned:
    (n, 7) rows [a (3), b (3), radius], each a segment along the box's longest axis. The box is cut along its
    middle axis into n strips about as wide as it is thin, so a flat box is not covered by one fat capsule."""
    half = np.abs(np.asarray(half, dtype=np.float64))
    order = np.argsort(-half)  # longest, middle, shortest axis
    long, mid, short = half[order]
    n = max(1, int(np.ceil(mid / max(short, 1e-9))))
    width = mid / n  # half width of a strip
    radius = float(np.hypot(width, short))
    rows = []
    for k in range(n):
        centre = np.zeros(3)
        centre[order[1]] = -mid + (2 * k + 1) * width
        offset = np.zeros(3)
        offset[order[0]] = long
        rows.append(np.concatenate([centre - offset, centre + offset, [radius]]))
    return np.array(rows)
