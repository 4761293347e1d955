"""Physical-law labels from simulator state (paper Appendix, Eqs 4-9).

Pure numpy functions, vectorised over leading batch dimensions (``...``).
Each docstring states the edge-case behaviour; a label of ``-1`` always means
"no label" (no contact, no motion, degenerate geometry) and callers must treat
it as such.  Angles are in degrees.
"""

from __future__ import annotations

import numpy as np

#: Names of the tool-object axes of T_fv (the ``tool_object_rot`` choices).
#: ``"X-Y"`` is the diagonal ``(X + Y) / sqrt(2)``, not X minus Y.
TOOL_OBJECT_AXES: tuple[str, ...] = ("X", "Y", "Z", "X-Y", "X-Z", "Y-Z")

_TOOL_OBJECT_VECTORS: tuple[tuple[float, float, float], ...] = (
    (1.0, 0.0, 0.0),
    (0.0, 1.0, 0.0),
    (0.0, 0.0, 1.0),
    (1.0, 1.0, 0.0),
    (1.0, 0.0, 1.0),
    (0.0, 1.0, 1.0),
)


def tool_object_axis(name: str) -> np.ndarray:
    """Unit direction (3,) in the T_fv frame of a ``TOOL_OBJECT_AXES`` name (``"X-Z"`` -> (X + Z) / sqrt(2))."""
    if name not in TOOL_OBJECT_AXES:
        raise ValueError(f"unknown tool-object axis {name!r}; known: {', '.join(TOOL_OBJECT_AXES)}")
    v = np.asarray(_TOOL_OBJECT_VECTORS[TOOL_OBJECT_AXES.index(name)])
    return v / np.linalg.norm(v)


#: Vectors shorter than this are "zero length" (no direction).
EPS = 1e-9


def _unit(v: np.ndarray, eps: float = EPS) -> tuple[np.ndarray, np.ndarray]:
    """``(v / |v|, |v| > eps)`` along the last axis; zero-length vectors stay zero."""
    norm = np.linalg.norm(v, axis=-1)
    valid = norm > eps
    return v / np.where(valid, norm, 1.0)[..., None], valid


# ------------------------------------------------------------------ Eq 4


def rotation_class(theta_deg: np.ndarray | float, c: float) -> np.ndarray:
    """Eq 4: rotation class ``floor(theta / c + 0.5)`` (int64, same shape as ``theta_deg``).

    This rounds to the nearest multiple of ``c``; exactly-halfway angles round
    up (towards +inf): ``rotation_class(2.5, 5) == 1``, ``rotation_class(-2.5, 5) == 0``.
    ``c`` must be > 0.
    """
    if not c > 0:
        raise ValueError(f"class constant c must be > 0, got {c!r}")
    return np.floor(np.asarray(theta_deg, dtype=float) / c + 0.5).astype(np.int64)


def euler_xyz_to_matrix(angles_deg: np.ndarray) -> np.ndarray:
    """Rotation matrices ``Rx(a) @ Ry(b) @ Rz(c)`` from ``(..., 3)`` angles ``(a, b, c)`` in degrees.

    This is the intrinsic X-Y-Z convention (scipy ``Rotation.from_euler("XYZ")``),
    the inverse of :func:`relative_euler_xyz`.
    """
    a, b, c = np.moveaxis(np.deg2rad(np.asarray(angles_deg, dtype=float)), -1, 0)
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rows = [
        [cb * cc, -cb * sc, sb],
        [ca * sc + sa * sb * cc, ca * cc - sa * sb * sc, -sa * cb],
        [sa * sc - ca * sb * cc, sa * cc + ca * sb * sc, ca * cb],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def relative_euler_xyz(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Euler angles (degrees, ``(..., 3)``) of the relative rotation ``R_a^T @ R_b``.

    ``R_a`` and ``R_b`` are ``(..., 3, 3)`` world-frame rotations (frame b seen
    from frame a).  Convention: intrinsic X-Y-Z, ``R = Rx(tx) Ry(ty) Rz(tz)``,
    with ``tx, tz`` in ``(-180, 180]`` and ``ty`` in ``[-90, 90]``.  At gimbal
    lock (``|cos ty| < 1e-9``) ``tz`` is set to 0 and ``tx`` carries the rest.
    """
    R = np.swapaxes(np.asarray(R_a, dtype=float), -1, -2) @ np.asarray(R_b, dtype=float)
    ty = np.arcsin(np.clip(R[..., 0, 2], -1.0, 1.0))
    locked = np.abs(np.cos(ty)) < 1e-9
    tx = np.where(locked, np.arctan2(R[..., 2, 1], R[..., 1, 1]), np.arctan2(-R[..., 1, 2], R[..., 2, 2]))
    tz = np.where(locked, 0.0, np.arctan2(-R[..., 0, 1], R[..., 0, 0]))
    return np.rad2deg(np.stack([tx, ty, tz], axis=-1))


def rotation_choice(theta_deg: np.ndarray | float, choices_deg: np.ndarray, c: float) -> np.ndarray:
    """Index of the Representation-Space choice for an angle (int64, shape of ``theta_deg``).

    The angle is classified with Eq 4, then mapped to the choice whose own
    class is nearest.  Angles beyond the covered range clip to the end choice
    (e.g. -40 deg with choices 0..-30 gives the -30 choice); on a tie between
    two choices the first in ``choices_deg`` wins.
    """
    k = rotation_class(theta_deg, c)
    classes = rotation_class(np.asarray(choices_deg, dtype=float).reshape(-1), c)
    return np.argmin(np.abs(k[..., None] - classes), axis=-1).astype(np.int64)


# ------------------------------------------------------------------ Eq 5


def box_face_centers(center: np.ndarray, half_extents: np.ndarray, R: np.ndarray) -> np.ndarray:
    """World positions ``(..., 6, 3)`` of the face centres of an oriented box.

    ``R`` (``(..., 3, 3)``) has the box axes as columns.  Face order:
    +X, -X, +Y, -Y, +Z, -Z (box frame).
    """
    local = np.repeat(np.eye(3), 2, axis=0) * np.tile([1.0, -1.0], 3)[:, None]  # (6, 3)
    local = local * np.asarray(half_extents, dtype=float)[..., None, :]
    world = np.einsum("...ij,...fj->...fi", np.asarray(R, dtype=float), local)
    return world + np.asarray(center, dtype=float)[..., None, :]


def relative_position_label(
    center: np.ndarray, face_centers: np.ndarray, anchors: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Eq 5: ``(i, j) = argmax_{i,j} cos(gv_i, h_j)``.

    ``gv_i = face_centers[i] - center`` (``face_centers`` is ``(..., 6, 3)``),
    ``h_j = anchors[j] - center`` (``anchors`` is ``(..., k, 3)``).  A
    zero-length vector (an anchor or face centre at the centre) has no
    direction and is excluded from the argmax; if every pair is excluded the
    result is ``(-1, -1)``.  Exact ties go to the first pair in row-major
    (i, then j) order.  Returns two int64 arrays of the batch shape.
    """
    c = np.asarray(center, dtype=float)[..., None, :]
    gv, gv_ok = _unit(np.asarray(face_centers, dtype=float) - c)
    h, h_ok = _unit(np.asarray(anchors, dtype=float) - c)
    cos = np.einsum("...id,...jd->...ij", gv, h)
    cos = np.where(gv_ok[..., :, None] & h_ok[..., None, :], cos, -np.inf)
    k = cos.shape[-1]
    flat = cos.reshape(*cos.shape[:-2], -1)
    best = np.argmax(flat, axis=-1)
    found = np.isfinite(np.max(flat, axis=-1))
    return np.where(found, best // k, -1).astype(np.int64), np.where(found, best % k, -1).astype(np.int64)


# ------------------------------------------------------------- Eqs 6 and 7


def binarize_contacts(forces: np.ndarray, threshold: float) -> np.ndarray:
    """Binary contact vector (uint8): 1 where the force magnitude is strictly above ``threshold``.

    ``forces`` holds one non-negative magnitude per sensor (``(..., 17)``); a
    force equal to the threshold counts as no contact.  ``threshold`` must be >= 0.
    """
    if not threshold >= 0:
        raise ValueError(f"contact threshold must be >= 0, got {threshold!r}")
    return (np.asarray(forces, dtype=float) > threshold).astype(np.uint8)


def jaccard(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Eq 7: Jaccard similarity ``|a & b| / |a | b|`` of binary vectors along the last axis.

    Inputs broadcast against each other; non-zero entries count as 1.  Two
    empty vectors have similarity 0 (not 1): no contact matches no pattern.
    """
    a = np.asarray(a) != 0
    b = np.asarray(b) != 0
    inter = np.sum(a & b, axis=-1)
    union = np.sum(a | b, axis=-1)
    return np.where(union > 0, inter / np.maximum(union, 1), 0.0)


def grasp_label(contact_binary: np.ndarray, grasp_matrix: np.ndarray) -> np.ndarray:
    """Eq 6: index of the grasp pattern with the highest Jaccard similarity (int64).

    ``contact_binary`` is ``(..., 17)``, ``grasp_matrix`` ``(n_patterns, 17)``.
    Ties go to the lowest pattern index.  When the best similarity is 0 (no
    contact at all, or contacts sharing no sensor with any pattern) the label
    is -1, "no grasp".
    """
    contacts = np.asarray(contact_binary)
    patterns = np.asarray(grasp_matrix)
    if contacts.shape[-1] != patterns.shape[-1]:
        raise ValueError(
            f"contact vector has {contacts.shape[-1]} sensors, grasp patterns have {patterns.shape[-1]}"
        )
    sim = jaccard(contacts[..., None, :], patterns)
    return np.where(np.max(sim, axis=-1) > 0, np.argmax(sim, axis=-1), -1).astype(np.int64)


# ------------------------------------------------------------------ Eq 8


def _check_tau(tau: float) -> None:
    """Eq 8 thresholds: sigma(-|d|) <= 0.5, so only 0 < tau < 0.5 is meaningful."""
    if not 0 < tau < 0.5:
        raise ValueError(f"tau must be in (0, 0.5) because sigma(-|det|) <= 0.5, got {tau!r}")


def _sigmoid_neg_abs(d: np.ndarray) -> np.ndarray:
    """``sigma(-|d|) = e^-|d| / (1 + e^-|d|)``, computed without overflow."""
    e = np.exp(-np.abs(d))
    return e / (1.0 + e)


def collinearity_det(points: np.ndarray) -> np.ndarray:
    """The determinant-like quantity of Eq 8 for contact positions ``(..., m, 3)``.

    ``S = sum_k (p_k - mean)(p_k - mean)^T`` is the 3x3 scatter matrix of the
    centred points.  Its plain determinant vanishes for any *coplanar* set
    (always, for 3 points), so we use the sum of its 2x2 principal minors
    (the product of its two largest eigenvalues when the points are coplanar):
    0 exactly when the points are collinear.  For three points it equals
    ``|(p1 - p0) x (p2 - p0)|^2 / 3``.  Units: length^4; m <= 2 gives 0.
    """
    p = np.asarray(points, dtype=float)
    c = p - p.mean(axis=-2, keepdims=True)
    S = np.einsum("...mi,...mj->...ij", c, c)
    minors = [S[..., i, i] * S[..., j, j] - S[..., i, j] ** 2 for i, j in ((0, 1), (0, 2), (1, 2))]
    return minors[0] + minors[1] + minors[2]


def coplanarity_det(normals: np.ndarray) -> np.ndarray:
    """The determinant of Eq 8 for contact normals ``(..., m, 3)``: ``det(sum_k n_k n_k^T)``.

    Normals are first scaled to unit length (zero-length normals stay zero and
    add nothing).  The Gram matrix is singular exactly when the normals span at
    most a plane, so the value is 0 for coplanar normals and for m <= 2.
    """
    n, _ = _unit(np.asarray(normals, dtype=float))
    return np.linalg.det(np.einsum("...mi,...mj->...ij", n, n))


def collinear_indicator(points: np.ndarray, tau: float) -> np.ndarray:
    """Eq 8 ``C_line``: 1 (uint8) where ``sigma(-|collinearity_det(points)|) > tau``.

    ``tau`` must lie in (0, 0.5): sigma(-0) = 0.5 is the largest value, so
    perfectly collinear points give 1 for every valid tau.  Equivalently the
    test is ``|det| < ln((1 - tau) / tau)``; mind the units (metres^4).
    """
    _check_tau(tau)
    return (_sigmoid_neg_abs(collinearity_det(points)) > tau).astype(np.uint8)


def coplanar_indicator(normals: np.ndarray, tau: float) -> np.ndarray:
    """Eq 8 ``C_plane``: 1 (uint8) where ``sigma(-|coplanarity_det(normals)|) > tau``.

    ``tau`` must lie in (0, 0.5), see :func:`collinear_indicator`.
    """
    _check_tau(tau)
    return (_sigmoid_neg_abs(coplanarity_det(normals)) > tau).astype(np.uint8)


# ------------------------------------------------------------------ Eq 9


def motion_label(joint_vel: np.ndarray, templates: np.ndarray, eps: float = EPS) -> np.ndarray:
    """Eq 9: index of the motion template with the highest cosine to ``joint_vel`` (int64).

    ``joint_vel`` is ``(..., 30)``, ``templates`` ``(n_templates, 30)``.  Ties
    go to the lowest template index.  The label is -1 when the velocity norm
    is <= ``eps`` (no motion) or when no template has a positive cosine (the
    motion goes against every template).  All-zero templates are never chosen.
    """
    v, moving = _unit(np.asarray(joint_vel, dtype=float), eps)
    t, t_ok = _unit(np.asarray(templates, dtype=float), eps)
    if v.shape[-1] != t.shape[-1]:
        raise ValueError(f"joint velocity has {v.shape[-1]} joints, templates have {t.shape[-1]}")
    cos = np.where(t_ok, v @ t.T, -np.inf)
    ok = moving & (np.max(cos, axis=-1) > 0)
    return np.where(ok, np.argmax(cos, axis=-1), -1).astype(np.int64)


def motion_choice(template_idx: np.ndarray | int, template_to_motion: np.ndarray) -> np.ndarray:
    """Map template indices to ``kinematic_motion`` choices (int64); -1 stays -1."""
    idx = np.asarray(template_idx, dtype=np.int64)
    table = np.asarray(template_to_motion, dtype=np.int64)
    if np.any(idx >= len(table)) or np.any(idx < -1):
        raise ValueError(f"template index out of range -1..{len(table) - 1}: {idx}")
    return np.where(idx >= 0, table[np.maximum(idx, 0)], -1).astype(np.int64)


# ------------------------------------------------------ tool-object rotation


def tool_object_rot_label(obj_z_in_fv_frame: np.ndarray, eps: float = EPS) -> np.ndarray:
    """Index into :data:`TOOL_OBJECT_AXES` of the axis best aligned with the object's Z (int64).

    ``obj_z_in_fv_frame`` (``(..., 3)``) is the object's Z axis expressed in the
    T_fv frame.  Alignment is ``|cos|``, so anti-parallel counts as aligned.
    Ties go to the lowest index (e.g. ``(1, 1, 1)`` -> ``X-Y``); a zero-length
    vector gives -1.
    """
    u, ok = _unit(np.asarray(obj_z_in_fv_frame, dtype=float), eps)
    axes, _ = _unit(np.asarray(_TOOL_OBJECT_VECTORS))
    score = np.abs(u @ axes.T)
    return np.where(ok, np.argmax(score, axis=-1), -1).astype(np.int64)
