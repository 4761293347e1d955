"""Label recovery (docs/guide/design.md "Labels"): recompute a demonstration's plan vector from its recorded data.

A demonstration (``prl.demo.Demo``, or its ``.npz``) holds the commanded plan ``a0..a5`` and what
the simulator recorded while executing it. :func:`recover_plan` ignores the plan and recomputes each
physical law with the pure label functions of :mod:`prl.labels` (paper Appendix, Eqs 4-9);
:func:`agreement` then says per dimension how often the recomputed label equals the commanded one.
Pure numpy: no simulator import (``.npz`` files are read by :func:`prl.demo.load_demo`, not through
``envs``). A label of -1 means "undeterminable from this recording" (stage never reached, tool not
in the hand, no motion) and never counts as agreement.

Which recorded frames each dimension uses, and why (stage indices are ``prl.stages.STAGES``):

* **a0, a1 (Eq 4)** -- Euler XYZ angles of the palm link rotation relative to T_gv,
  ``relative_euler_xyz(R_gv, R_palm)`` (the executor commands ``R_palm = R_gv Rx(a0) Rz(a1)``, so the
  angles are ``(a0, ~0, a1)``), classified with each dimension's class constant ``c``. T_gv's axes
  are the tool actor's axes (``tool_gv_local`` is a centre and half extents, no rotation), so
  ``R_gv`` is the ``tool_pose`` rotation. Frame: the **last record before the hand first touches
  anything** during approach/grasp (at most the end of the approach stage): the palm has reached its
  grasp orientation (the approach only translates along the palm normal) and the tool still lies
  undisturbed. On the 46 sample hammer demos this reproduces the commanded angles to 0.2 deg, except
  for commanded a0 = -30 deg, which the hand reaches only to -26..-29 deg (the arm stops short: ARRx
  2-4 deg and ARTz ~1 cm from their targets), so -27.4 deg and above read as -25 deg (3 of those 6
  demos, all failed).
  At the end of the grasp stage (kept as ``euler_grasp_deg``) the angle is no longer the hand's
  choice: closing the medium-wrap fingers rolls the handle about its long axis (T_gv X, the a0 axis)
  by 3.9-5.0 deg on every expert demo, which crosses the 2.5 deg class boundary (c = 5), so grasp-end
  labels read -5 deg instead of 0 for the expert plan [0,3,2,0,0,1]: a0 would agree on 0/10 and
  a1 on 7/10 of the successful samples instead of 10/10 each. A palm that lands on the handle
  during the approach (ok/ep507) rolls it by 20+ deg before the fingers close.
* **a2 (Eq 5)** -- ``relative_position_label`` on the T_gv box and the six palm anchors at the same
  **pre-contact record** as a0/a1, with T_gv's faces turned by the palm's rotation relative to T_gv
  (``R_palm R_gv^T``, the rotation a0/a1 label): the executor puts the chosen anchor on T_gv's centre line
  along the *palm's* normal, so in the tool's own frame a palm tilted by a0 or twisted by a1 has the
  neighbouring row best aligned with a face (2026-12-01, 2,000 hammer demos: agreement 95% untilted, 58% at
  a0 = -15 deg, 3% at -30; the tweeze expert, tilted -10 deg and twisted -20 deg, read anchor 3 for its
  commanded 4 on every episode until 2026-12-02). Turning the faces with the palm separates the relative
  position from the relative rotation; untilted grasps read as before. The pre-contact record: the
  relative position is a pre-grasp law, and the fingers move the tool while they close (on 2,000
  executor-v2 hammer demos the handle moved a median of 9 mm in the palm during the grasp stage; Eq 5
  agreed with the commanded anchor on 56% of them at the end of the grasp, on 74% before contact,
  both in the tool's frame). The recording
  holds the anchors and T_gv at the end of the grasp (``anchors_at_grasp``, ``gv_center/gv_rot``);
  both are rigid in their bodies (palm, tool), so they are carried back to the pre-contact record with
  the recorded palm and tool poses (:func:`_before_contact`). The label is the anchor index ``j`` of
  the best (face, anchor) pair. The grasp-end reading is kept as ``anchor_grasp_end``, and a variant
  that uses the palm normal instead of the box faces as ``anchor_palm_normal``, for diagnosis.
* **a3 (Eqs 6-7)** -- each sensor is binarised with ``CONTACT_THRESHOLD_N`` = 1 N (the hammer
  weighs ~2.3 N; 99% of non-zero sensor forces during the lift are above 1.3 N, the rest are
  grazing touches), ``grasp_label`` per record of the **lift** stage (the tool hangs in the hand:
  only the grasp holds it), majority vote over those records (records without contact vote -1).
* **a4 (Eq 9)** -- ``motion_label`` on the mean joint velocity over the **motion** stage, computed as
  the qpos displacement from its first to its last record (Eq 9's cosine is scale-free, so the
  displacement is used as is). The instantaneous ``qvel`` samples are dominated by finger chatter
  against the handle (1-2 rad/s on THJ3 while the hand holds still) and pick wrist or finger
  templates at random before the strike; the displacement integrates that zero-mean jitter away.
  A displacement of norm <= ``MIN_MOTION_NORM`` (mixed units, 1 cm / 0.6 deg) is "no motion" (-1).
* **a5** -- ``tool_object_rot_label`` of the object's Z axis expressed in the tool frame (= T_fv
  frame: ``tool_fv_local`` has no rotation either), at the record of the **place or motion** stage
  in which the tool is still held (>= ``MIN_HOLD_CONTACTS`` sensors in contact) and T_fv is
  closest to the object's frame origin: the moment the tool reaches the object, which is where the
  executor aligns the axis. The end of the place stage is *not* that moment: for the wrist motions
  the place pose is the contact pose with the wrist swung back by the whole motion amplitude
  (0.45 rad), so the expert's head reads ~20 deg off Y there (Y-Z on all six expert demos). No held
  record in place/motion (the tool was dropped in transport) gives -1.

Findings on the 2,000 demos of the paper profile (executor v2, 250 Hz; ``python -m prl.label_recovery
<synthesis dir>``, 2026-12-01): a0 93.8%, a1 100%, a2 74.2%, a3 91.2%, a4 96.0%, a5 93.2%.

* a0: the arm stops short of large tilts (commanded -30 deg reads -24.4 deg, -25 reads -21.6, medians
  before contact), so 92 of the 104 demos at -30 read -25 and 32 of the 111 at -25 read -20.
* a2: the misses are tilted grasps. Eq 5 compares anchor directions with T_gv's face normals; with the
  palm tilted about the handle the commanded anchor, on the palm normal, is no longer the one best
  aligned with a face, the neighbouring row is. Agreement by commanded a0 (0, -5, ..., -30 deg): 95%,
  95%, 87%, 58%, 24%, 7%, 3%. The palm-normal diagnostic (``anchor_palm_normal``) equals the commanded
  anchor on all 2,000: the hand did put that anchor on T_gv's centre line. (These are the tool-frame
  readings of 2026-12-01; since 2026-12-02 Eq 5 turns T_gv's faces with the palm, above.)
* a3: medium wrap 96.2% (1,731 of 1,800); on the hammer's round handle a parallel extension reads as
  itself on 40 of 89 and a precision disk on 21 of 79 (their other demos read palmar pinch: only the
  index and thumb reach the 3 cm handle); palmar pinch 32 of 32.
* a5: the misses (136) are hammers that turned in the hand on the way: between the end of the lift
  and the alignment record the tool turned a median 52 deg in the palm's frame on the misses, 4 deg on
  the matches, so the executed alignment is not the commanded one.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prl import labels
from prl.demo import load_demo
from prl.plb import PhysicalLawsBank, load_plb
from prl.stages import STAGES

_APPROACH, _GRASP, _LIFT, _PLACE, _MOTION = (STAGES.index(s) for s in ("approach", "grasp", "lift", "place", "motion"))

CONTACT_THRESHOLD_N = 1.0
"""A sensor is in contact when its force is strictly above this (N); see the module docstring."""
MIN_HOLD_CONTACTS = 2
"""The tool counts as held in a record with at least this many sensors in contact."""
MIN_MOTION_NORM = 0.01
"""Motion-stage joint displacement norm at or below which there is no motion (a4 = -1)."""

#: Recorded arrays :func:`recover_plan` reads.
REQUIRED_FIELDS: tuple[str, ...] = (
    "stage", "qpos", "force", "palm_pose", "tool_pose", "object_pose",
    "anchors_at_grasp", "gv_center", "gv_half", "gv_rot", "tool_fv_local",
)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of quaternions ``(..., 4)`` in ``[qw, qx, qy, qz]`` order.

    The quaternion is normalised first (so a non-unit recording still gives a rotation).
    """
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def point_box_distance(point: np.ndarray, center: np.ndarray, half: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Distance from ``point`` (``(..., 3)``) to an oriented box (0 inside); ``R`` has the box axes as columns."""
    local = np.einsum("...ji,...j->...i", np.asarray(R, dtype=float), np.asarray(point, float) - center)
    return np.linalg.norm(np.maximum(np.abs(local) - np.asarray(half, dtype=float), 0.0), axis=-1)


@dataclass(frozen=True)
class RecoveredLabels:
    """A plan vector recomputed from a recording, with what each label was computed from."""

    plan: np.ndarray
    """(6,) int64 recovered plan index vector; -1 where the recording does not determine a dimension."""
    contact_record: int
    """Record used for a0/a1: the last one before the first hand contact (-1 if none)."""
    euler_contact_deg: np.ndarray
    """(3,) palm-vs-T_gv Euler XYZ angles at ``contact_record`` (a0 from [0], a1 from [2]); NaN if none."""
    euler_grasp_deg: np.ndarray
    """(3,) the same angles at the end of the grasp stage (after the fingers closed); NaN if none."""
    anchor_face: int
    """T_gv face (+X, -X, +Y, -Y, +Z, -Z order) of Eq 5's best pair; -1 if none."""
    anchor_cos: float
    """Cosine of Eq 5's best (face, anchor) pair; NaN if none."""
    anchor_palm_normal: int
    """Diagnostic: the anchor whose direction from T_gv's centre is closest to the palm normal; -1 if none."""
    anchor_grasp_end: int
    """Diagnostic: Eq 5's anchor at the end of the grasp stage, after the fingers moved the tool; -1 if none."""
    contact_fraction: np.ndarray
    """(17,) fraction of lift records in which each sensor is in contact."""
    grasp_jaccard: np.ndarray
    """(n_patterns,) mean Jaccard similarity (Eq 7) of the lift records' contacts with each pattern."""
    grasp_votes: np.ndarray
    """(n_patterns,) lift records whose Eq 6 label is each pattern."""
    motion_displacement: np.ndarray
    """(30,) joint displacement over the motion stage (the Eq 9 velocity direction); zeros if none."""
    motion_cosine: np.ndarray
    """(n_templates,) cosine of ``motion_displacement`` with each template; NaN if none."""
    object_z_in_tool: np.ndarray
    """(3,) unit object Z axis in the tool (= T_fv) frame at ``tool_object_record``; NaN if none."""
    tool_object_record: int
    """Record used for a5 (tool held, T_fv closest to the object); -1 if none."""
    tool_object_angle_deg: float
    """Angle between the object's Z and the chosen T_fv axis (0..90 deg); NaN if none."""
    notes: tuple[str, ...] = field(default=())
    """Why a dimension is -1, in words."""


# --------------------------------------------------------------------------- recording access


def _field(demo: Any, name: str) -> np.ndarray:
    try:
        return np.asarray(getattr(demo, name))
    except AttributeError:
        raise ValueError(f"demo has no recorded array {name!r}; needed: {', '.join(REQUIRED_FIELDS)}") from None


# --------------------------------------------------------------------------- per dimension


def _contacts(force: np.ndarray) -> np.ndarray:
    return labels.binarize_contacts(force, CONTACT_THRESHOLD_N)


def _hand_tool_rotation(stage: np.ndarray, force: np.ndarray, palm_R: np.ndarray, tool_R: np.ndarray
                        ) -> tuple[int, np.ndarray, np.ndarray]:
    """(pre-contact record, Euler angles there, Euler angles at the grasp end); -1 / NaN where absent."""
    nan3 = np.full(3, np.nan)
    grasp_idx = np.nonzero(stage == _GRASP)[0]
    euler_grasp = labels.relative_euler_xyz(tool_R[grasp_idx[-1]], palm_R[grasp_idx[-1]]) if grasp_idx.size else nan3
    approach_idx = np.nonzero(stage == _APPROACH)[0]
    if approach_idx.size == 0:
        return -1, nan3, euler_grasp
    window = np.nonzero((stage == _APPROACH) | (stage == _GRASP))[0]
    touching = window[_contacts(force[window]).any(axis=-1)]
    k = int(approach_idx[-1])
    if touching.size:
        k = min(k, int(touching[0]) - 1)
    k = max(k, 0)
    return k, labels.relative_euler_xyz(tool_R[k], palm_R[k]), euler_grasp


def _pose_matrix(position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rotation, position
    return m


def _before_contact(stage: np.ndarray, k: int, palm_pose: np.ndarray, palm_R: np.ndarray, tool_pose: np.ndarray,
                    tool_R: np.ndarray, anchors_end: np.ndarray, gv_center_end: np.ndarray, gv_rot_end: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The palm anchors and T_gv (centre, axes) at record ``k``, moved rigidly from their grasp-end values.

    The anchors are fixed in the palm and T_gv in the tool, so their grasp-end world positions are carried
    into the palm / tool frame of the last grasp record and out again at record ``k``. NaN if either is
    missing (no grasp stage, no pre-contact record)."""
    grasp = np.nonzero(stage == _GRASP)[0]
    nan = (np.full_like(anchors_end, np.nan), np.full(3, np.nan), np.full((3, 3), np.nan))
    if k < 0 or grasp.size == 0 or not (np.all(np.isfinite(anchors_end)) and np.all(np.isfinite(gv_rot_end))):
        return nan
    g = int(grasp[-1])
    palm_g, palm_k = _pose_matrix(palm_pose[g, :3], palm_R[g]), _pose_matrix(palm_pose[k, :3], palm_R[k])
    tool_g, tool_k = _pose_matrix(tool_pose[g, :3], tool_R[g]), _pose_matrix(tool_pose[k, :3], tool_R[k])
    move_palm, move_tool = palm_k @ np.linalg.inv(palm_g), tool_k @ np.linalg.inv(tool_g)
    anchors = anchors_end @ move_palm[:3, :3].T + move_palm[:3, 3]
    return anchors, move_tool[:3, :3] @ gv_center_end + move_tool[:3, 3], move_tool[:3, :3] @ gv_rot_end


def _grasp(stage: np.ndarray, force: np.ndarray, patterns: np.ndarray
           ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """(majority Eq 6 label, per-sensor contact fraction, mean Jaccard, votes) over the lift records.

    A task without a lift stage (a cap that stays on its bottle) votes over the second half of the grasp
    stage instead: the fingers have closed and nothing else touches the tool yet."""
    n = patterns.shape[0]
    lift = np.nonzero(stage == _LIFT)[0]
    if lift.size == 0 and np.any(stage > _GRASP):
        grasp = np.nonzero(stage == _GRASP)[0]
        lift = grasp[grasp.size // 2:]
    if lift.size == 0:
        return -1, np.zeros(force.shape[-1]), np.zeros(n), np.zeros(n, np.int64)
    contacts = _contacts(force[lift])
    per_record = labels.grasp_label(contacts, patterns)
    votes = np.bincount(per_record[per_record >= 0], minlength=n)
    jac = labels.jaccard(contacts[:, None, :], patterns).mean(axis=0)
    no_contact = int(np.sum(per_record < 0))
    label = int(np.argmax(votes)) if votes.max(initial=0) > no_contact else -1
    return label, contacts.mean(axis=0), jac, votes


def _motion(stage: np.ndarray, qpos: np.ndarray, templates: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """(Eq 9 template index or -1, motion-stage displacement, cosine with each template)."""
    idx = np.nonzero(stage == _MOTION)[0]
    if idx.size < 2:
        return -1, np.zeros(qpos.shape[-1]), np.full(templates.shape[0], np.nan)
    disp = qpos[idx[-1]] - qpos[idx[0]]
    unit_t = templates / np.linalg.norm(templates, axis=1, keepdims=True)
    norm = np.linalg.norm(disp)
    cos = unit_t @ disp / norm if norm > 0 else np.full(templates.shape[0], np.nan)
    return int(labels.motion_label(disp, templates, eps=MIN_MOTION_NORM)), disp, cos


def _tool_object(stage: np.ndarray, force: np.ndarray, tool_pose: np.ndarray, tool_R: np.ndarray,
                 object_pose: np.ndarray, fv_local: np.ndarray) -> tuple[int, int, np.ndarray, float]:
    """(label index into TOOL_OBJECT_AXES or -1, record, object Z in the tool frame, angle)."""
    nan3 = np.full(3, np.nan)
    held = _contacts(force).sum(axis=-1) >= MIN_HOLD_CONTACTS
    cand = np.nonzero(((stage == _PLACE) | (stage == _MOTION)) & held)[0]
    if cand.size == 0:
        return -1, -1, nan3, float("nan")
    R = tool_R[cand]
    fv_center = tool_pose[cand, :3] + np.einsum("tij,j->ti", R, fv_local[:3])
    dist = point_box_distance(object_pose[cand, :3], fv_center, fv_local[3:], R)
    k = int(cand[np.argmin(dist)])
    obj_z = quat_to_matrix(object_pose[k, 3:])[:, 2]
    z_tool = tool_R[k].T @ obj_z
    label = int(labels.tool_object_rot_label(z_tool))
    axis = labels.tool_object_axis(labels.TOOL_OBJECT_AXES[label])
    cos = abs(float(z_tool @ axis)) / np.linalg.norm(z_tool)
    return label, k, z_tool / np.linalg.norm(z_tool), float(np.degrees(np.arccos(min(1.0, cos))))


# --------------------------------------------------------------------------- public API


def recover_plan(demo: Any, plb: PhysicalLawsBank | None = None) -> RecoveredLabels:
    """Recompute the plan vector of ``demo`` from its recorded arrays alone (never reads ``demo.plan``).

    ``demo`` is a ``prl.demo.Demo``, or anything with the arrays of
    ``REQUIRED_FIELDS`` as attributes (shapes as in ``prl.demo``). The frames used per dimension
    are described in the module docstring. Dimensions are those of ``plb`` in plan order
    (default catalogue if None): rotation X, rotation Z, anchor, grasp pattern, motion, tool-object axis.
    """
    plb = plb or load_plb()
    stage = _field(demo, "stage").astype(np.int64)
    force = _field(demo, "force").astype(float)
    qpos = _field(demo, "qpos").astype(float)
    palm_pose, tool_pose, object_pose = (_field(demo, n).astype(float) for n in ("palm_pose", "tool_pose", "object_pose"))
    if not (len(stage) == len(force) == len(qpos) == len(palm_pose) == len(tool_pose) == len(object_pose)):
        raise ValueError("recorded arrays have different numbers of records: "
                         f"stage {len(stage)}, force {len(force)}, qpos {len(qpos)}, palm_pose {len(palm_pose)}, "
                         f"tool_pose {len(tool_pose)}, object_pose {len(object_pose)}")
    palm_R = quat_to_matrix(palm_pose[:, 3:])
    tool_R = quat_to_matrix(tool_pose[:, 3:])
    dims = plb.dims
    plan = np.full(len(dims), -1, dtype=np.int64)
    notes: list[str] = []

    # a0, a1: Eq 4 on the palm vs T_gv rotation just before the hand touches anything
    k_contact, euler_c, euler_g = _hand_tool_rotation(stage, force, palm_R, tool_R)
    if k_contact >= 0:
        for d, angle in ((0, euler_c[0]), (1, euler_c[2])):
            plan[d] = labels.rotation_choice(angle, np.asarray(dims[d].choices, dtype=float), dims[d].class_constant)
    else:
        notes.append("no approach stage recorded: a0/a1 undetermined")

    # a2: Eq 5 on T_gv and the anchors at the pre-contact record of a0/a1 (the grasp-end reading is kept)
    anchors_end = _field(demo, "anchors_at_grasp").astype(float)
    gv_center_end, gv_half, gv_rot_end = (_field(demo, n).astype(float) for n in ("gv_center", "gv_half", "gv_rot"))
    anchors, gv_center, gv_rot = _before_contact(stage, k_contact, palm_pose, palm_R, tool_pose, tool_R,
                                                 anchors_end, gv_center_end, gv_rot_end)
    face, cos_best, palm_normal_anchor, anchor_end = -1, float("nan"), -1, -1
    if np.all(np.isfinite(anchors_end)) and np.all(np.isfinite(gv_rot_end)):
        faces_end = labels.box_face_centers(gv_center_end, gv_half, gv_rot_end)
        anchor_end = int(labels.relative_position_label(gv_center_end, faces_end, anchors_end)[1])
    if np.all(np.isfinite(anchors)) and np.all(np.isfinite(gv_rot)):
        # Eq 5 in the frame the plan acts in: T_gv's faces turned with the palm's rotation relative to T_gv (what
        # a0/a1 label), so a tilted or twisted palm does not read the neighbouring anchor row (see the docstring)
        to_palm = palm_R[k_contact] @ gv_rot.T
        faces = gv_center + (labels.box_face_centers(gv_center, gv_half, gv_rot) - gv_center) @ to_palm.T
        face, j = (int(x) for x in labels.relative_position_label(gv_center, faces, anchors))
        if j >= 0:
            plan[2] = dims[2].index(j)
            g = (faces[face] - gv_center) / np.linalg.norm(faces[face] - gv_center)
            h = (anchors[j] - gv_center) / np.linalg.norm(anchors[j] - gv_center)
            cos_best = float(g @ h)
        normal = palm_R[k_contact][:, 1]  # +Y_palm: from the handle towards the palm
        h_all = anchors - gv_center
        palm_normal_anchor = int(np.argmax(h_all @ normal / np.linalg.norm(h_all, axis=1)))
    else:
        notes.append("no anchors/T_gv at grasp (grasp stage not completed): a2 undetermined")

    # a3: Eqs 6-7, majority over the lift records
    patterns = plb.grasp_matrix()
    g_label, contact_frac, jac, votes = _grasp(stage, force, patterns)
    if g_label >= 0:
        plan[3] = g_label
    else:
        notes.append("no contact in most lift records (tool not held): a3 undetermined")

    # a4: Eq 9 on the motion-stage displacement
    templates = plb.template_matrix()
    t_label, disp, m_cos = _motion(stage, qpos, templates)
    if t_label >= 0:
        plan[4] = int(labels.motion_choice(t_label, plb.template_to_motion))
    else:
        notes.append("no joint motion in the motion stage: a4 undetermined")

    # a5: object Z in the T_fv frame when the held tool reaches the object
    fv_local = _field(demo, "tool_fv_local").astype(float).reshape(-1)
    o_label, k_obj, z_tool, angle = _tool_object(stage, force, tool_pose, tool_R, object_pose, fv_local)
    if o_label >= 0:
        plan[5] = dims[5].index(labels.TOOL_OBJECT_AXES[o_label])
    else:
        notes.append("tool not held in any place/motion record: a5 undetermined")

    return RecoveredLabels(
        plan=plan, contact_record=k_contact, euler_contact_deg=euler_c, euler_grasp_deg=euler_g,
        anchor_face=face, anchor_cos=cos_best, anchor_palm_normal=palm_normal_anchor, anchor_grasp_end=anchor_end,
        contact_fraction=contact_frac, grasp_jaccard=jac, grasp_votes=votes,
        motion_displacement=disp, motion_cosine=m_cos, object_z_in_tool=z_tool,
        tool_object_record=k_obj, tool_object_angle_deg=angle, notes=tuple(notes),
    )


def agreement(commanded: np.ndarray | Sequence[Sequence[int]], recovered: np.ndarray | Sequence[Sequence[int]]
              ) -> np.ndarray:
    """Per-dimension fraction (``(D,)`` float) of demos whose recovered label equals the commanded one.

    Both are ``(N, D)`` integer arrays; a recovered -1 is a disagreement. ``N`` must be >= 1.
    """
    c = np.asarray(commanded, dtype=np.int64)
    r = np.asarray(recovered, dtype=np.int64)
    if c.ndim != 2 or c.shape != r.shape:
        raise ValueError(f"commanded and recovered must be (N, D) arrays of one shape, got {c.shape} and {r.shape}")
    if c.shape[0] == 0:
        raise ValueError("no demos to compare (N = 0)")
    return np.mean(c == r, axis=0)


def format_agreement(fractions: np.ndarray, n: int, plb: PhysicalLawsBank | None = None,
                     unacted: Sequence[str] = ()) -> str:
    """A readable table: one line per dimension with its name, agreement percentage and count of ``n``; the
    dimensions named in ``unacted`` (a task's ``unacted_dims``) are marked and left out of the acted mean."""
    plb = plb or load_plb()
    fractions = np.asarray(fractions, dtype=float)
    if fractions.shape != (len(plb.dims),):
        raise ValueError(f"expected {len(plb.dims)} fractions, got shape {fractions.shape}")
    unknown = sorted(set(unacted) - set(plb.dim_names))
    if unknown:
        raise ValueError(f"unknown dimension(s) {unknown}; known: {list(plb.dim_names)}")
    width = max(len(d.name) for d in plb.dims)
    lines = [f"label agreement over {n} demos (recovered == commanded)"]
    for i, (d, f) in enumerate(zip(plb.dims, fractions, strict=True)):
        mark = "  (not acted on by this task)" if d.name in unacted else ""
        lines.append(f"  a{i} {d.name:<{width}}  {100 * f:6.1f}%  ({round(float(f) * n)}/{n}){mark}")
    lines.append(f"  mean over acted dimensions  {100 * acted_mean(fractions, plb, unacted):6.1f}%")
    return "\n".join(lines)


def acted_mean(fractions: np.ndarray, plb: PhysicalLawsBank | None = None, unacted: Sequence[str] = ()) -> float:
    """Mean agreement over the dimensions not named in ``unacted``."""
    plb = plb or load_plb()
    acted = [f for name, f in zip(plb.dim_names, np.asarray(fractions, dtype=float), strict=True) if name not in unacted]
    return float(np.mean(acted)) if acted else float("nan")


def format_agreement_by(commanded: np.ndarray, recovered: np.ndarray, dim: int, by: int,
                        plb: PhysicalLawsBank | None = None) -> str:
    """Agreement of dimension ``dim`` for each commanded choice of dimension ``by`` (e.g. the anchor a2
    per commanded tilt a0): one line per choice that occurs, ``count agreeing / count``."""
    plb = plb or load_plb()
    c, r = np.asarray(commanded, dtype=np.int64), np.asarray(recovered, dtype=np.int64)
    for d in (dim, by):
        if not 0 <= d < len(plb.dims):
            raise ValueError(f"dimension index must be in 0..{len(plb.dims) - 1}, got {d}")
    lines = [f"a{dim} {plb.dims[dim].name} agreement by commanded a{by} {plb.dims[by].name}"]
    for k, choice in enumerate(plb.dims[by].choices):
        rows = c[:, by] == k
        if rows.any():
            hit = int(np.sum(c[rows, dim] == r[rows, dim]))
            lines.append(f"  {str(choice):>20}: {hit}/{int(rows.sum())} = {hit / rows.sum():.2f}")
    return "\n".join(lines)


# --------------------------------------------------------------------------- CLI


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Recover plan labels from demos (*.npz under DIR, recursively) "
                                     "and print per-dimension agreement with the commanded plans.")
    parser.add_argument("dir", type=Path, help="directory searched recursively for *.npz demos")
    parser.add_argument("--all", action="store_true", help="include failed demos (default: successful only)")
    parser.add_argument("--verbose", "-v", action="store_true", help="one line per demo")
    parser.add_argument("--by", nargs=2, type=int, action="append", default=[], metavar=("DIM", "BY"),
                        help="also print dimension DIM's agreement per commanded choice of dimension BY "
                             "(e.g. --by 2 0: the anchor per tilt; --by 3 3: each grasp pattern); repeatable")
    args = parser.parse_args(argv)
    if not args.dir.is_dir():
        parser.error(f"not a directory: {str(args.dir)!r}")
    plb = load_plb()
    paths = sorted(args.dir.rglob("*.npz"))
    commanded, recovered = [], []
    for path in paths:
        rec = load_demo(path)
        if not (rec.success or args.all):
            continue
        out = recover_plan(rec, plb)
        commanded.append(rec.plan.astype(np.int64))
        recovered.append(out.plan)
        if args.verbose:
            e = out.euler_contact_deg
            print(f"{path.relative_to(args.dir)}: success={rec.success} commanded {rec.plan.tolist()} "
                  f"recovered {out.plan.tolist()} (rot {e[0]:+.1f}/{e[2]:+.1f} deg, "
                  f"grasp-end {out.euler_grasp_deg[0]:+.1f}/{out.euler_grasp_deg[2]:+.1f}, "
                  f"a5 off {out.tool_object_angle_deg:.0f} deg){'; ' + '; '.join(out.notes) if out.notes else ''}")
    if not commanded:
        print(f"no {'' if args.all else 'successful '}demos under {args.dir}")
        return 1
    frac = agreement(np.stack(commanded), np.stack(recovered))
    print(format_agreement(frac, len(commanded), plb))
    for dim, by in args.by:
        print(format_agreement_by(np.stack(commanded), np.stack(recovered), dim, by, plb))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
