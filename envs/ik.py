"""Forward and inverse kinematics of the 30-DoF hand-arm (pytorch-kinematics, from the URDF).

The arm is 3 prismatic joints along world X, Y, Z followed by 3 revolute joints about the
local X, Y, Z axes through the point (ARTx, ARTy, ARTz) (``assets/hand/shadow_kinematics.yaml``),
so for fixed wrist and finger joints the palm pose is

    T_palm = root * Trans(ART) * Rx(ARRx) Ry(ARRy) Rz(ARRz) * M(wrist)

with M(wrist) the arm-zero forward kinematics of the palm. :func:`solve_palm_pose` inverts it
in closed form (an XYZ Euler decomposition, choosing the branch closest to ``q_init``) and
checks the result with pytorch-kinematics' forward kinematics; if that check ever misses the
tolerance it refines with pytorch-kinematics' ``PseudoInverseIK``. All vectors are in
``JOINT_NAMES`` order (which is also the chain's joint order; asserted).
"""

from __future__ import annotations

import functools
import re
from typing import Any

import numpy as np
import torch

from envs.hand_model import URDF_PATH, default_spec, palm_anchors
from prl.constants import JOINT_NAMES, N_ANCHORS
from prl.geometry import rot_x, rot_y, rot_z

PALM_LINK = "palm"
ARM = slice(0, 6)
_POS_TOL = 1e-4
_ROT_TOL = np.deg2rad(0.05)


@functools.lru_cache(maxsize=1)
def _chain() -> Any:
    """The pytorch-kinematics chain of the hand-arm (float64, CPU), built once per process."""
    import pytorch_kinematics as pk  # heavy (torch + its own kinematics): loaded on the first IK call

    text = URDF_PATH.read_text()
    # pytorch-kinematics only needs the kinematics; drop the geometry (it does not know <capsule>).
    text = re.sub(r"\s*<(visual|collision)\b.*?</\1>", "", text, flags=re.DOTALL)
    chain = pk.build_chain_from_urdf(text.encode()).to(dtype=torch.float64)
    names = tuple(chain.get_joint_parameter_names())
    assert names == JOINT_NAMES, f"chain joints {names} != JOINT_NAMES"
    return chain


def _as_q(q: Any) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64).reshape(-1)
    if q.shape != (len(JOINT_NAMES),):
        raise ValueError(f"joint vector must have {len(JOINT_NAMES)} values, got {q.shape[0]}")
    return q


def link_pose(q: Any, link: str = PALM_LINK, root: np.ndarray | None = None) -> np.ndarray:
    """World 4x4 pose of ``link`` for joint vector ``q`` (30,); ``root``: 4x4 pose of the
    articulation root (identity by default, as in the agent's keyframes)."""
    chain = _chain()
    th = torch.as_tensor(_as_q(q)[None], dtype=torch.float64)
    fk = chain.forward_kinematics(th, frame_indices=chain.get_frame_indices(link))
    matrix = fk[link].get_matrix()[0].numpy()
    return matrix if root is None else np.asarray(root, dtype=np.float64) @ matrix


def link_poses(qs: Any, links: list[str], root: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """World 4x4 poses (K, 4, 4) of each of ``links`` for the joint vectors ``qs`` (K, 30), in one batched pass
    (``root`` as in :func:`link_pose`)."""
    qs = np.asarray(qs, dtype=np.float64).reshape(-1, len(JOINT_NAMES))
    fk = _chain().forward_kinematics(torch.as_tensor(qs))
    root = np.eye(4) if root is None else np.asarray(root, dtype=np.float64)
    return {name: np.einsum("ij,kjl->kil", root, fk[name].get_matrix().numpy()) for name in links}


def palm_pose(q: Any, root: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), rotation (3, 3)) of the palm link frame in the world."""
    m = link_pose(q, PALM_LINK, root)
    return m[:3, 3].copy(), m[:3, :3].copy()


def anchors_world(q: Any, root: np.ndarray | None = None) -> np.ndarray:
    """(6, 3) world positions of the palm anchor points for joint vector ``q``."""
    p, r = palm_pose(q, root)
    return p + palm_anchors() @ r.T


def anchor_world(q: Any, i: int, root: np.ndarray | None = None) -> np.ndarray:
    """(3,) world position of palm anchor ``i`` (0..5) for joint vector ``q``."""
    if not 0 <= int(i) < N_ANCHORS:
        raise ValueError(f"anchor index must be in 0..{N_ANCHORS - 1}, got {i!r}")
    return anchors_world(q, root)[int(i)]


def _euler_xyz(r: np.ndarray) -> list[np.ndarray]:
    """Both (a, b, c) with Rx(a) Ry(b) Rz(c) = r (one if at gimbal lock)."""
    b = np.arcsin(np.clip(r[0, 2], -1.0, 1.0))
    if abs(np.cos(b)) < 1e-9:
        return [np.array([np.arctan2(r[2, 1], r[1, 1]), b, 0.0])]
    a = np.arctan2(-r[1, 2], r[2, 2])
    c = np.arctan2(-r[0, 1], r[0, 0])
    return [np.array([a, b, c]), np.array([a + np.pi, np.pi - b, c + np.pi])]


def _wrap(x: np.ndarray) -> np.ndarray:
    return (np.asarray(x) + np.pi) % (2 * np.pi) - np.pi


def rotation_error(r_a: np.ndarray, r_b: np.ndarray) -> float:
    """Angle (rad) of the rotation between two rotation matrices."""
    cos = (np.trace(np.asarray(r_a).T @ np.asarray(r_b)) - 1.0) / 2.0
    return float(np.arccos(np.clip(cos, -1.0, 1.0)))


def solve_palm_pose(target_pos: Any, target_R: Any, q_init: Any, finger_q: Any = None,
                    point: Any = None, root: np.ndarray | None = None) -> np.ndarray:
    """Arm joints that put the palm at (``target_pos``, ``target_R``); returns q (30,).

    Wrist (WRJ2, WRJ1) come from ``q_init``, fingers from ``finger_q`` (22 values, or a full
    30-vector whose finger part is used) or else from ``q_init``. ``point`` (3,) is a point in
    the palm frame (e.g. an anchor) that ``target_pos`` refers to; the palm-frame origin by
    default. Raises ``ValueError`` when the target is out of the arm's joint limits.
    """
    q = _as_q(q_init).copy()
    if finger_q is not None:
        fq = np.asarray(finger_q, dtype=np.float64).reshape(-1)
        if fq.shape[0] == len(JOINT_NAMES):
            fq = fq[8:]
        if fq.shape[0] != len(JOINT_NAMES) - 8:
            raise ValueError(f"finger_q must have 22 (or 30) values, got {fq.shape[0]}")
        q[8:] = fq
    target_pos = np.asarray(target_pos, dtype=np.float64).reshape(3)
    target_R = np.asarray(target_R, dtype=np.float64).reshape(3, 3)
    local = np.zeros(3) if point is None else np.asarray(point, dtype=np.float64).reshape(3)
    if root is not None:
        inv = np.linalg.inv(np.asarray(root, dtype=np.float64))
        target_pos = inv[:3, :3] @ target_pos + inv[:3, 3]
        target_R = inv[:3, :3] @ target_R
    q_zero = q.copy()
    q_zero[ARM] = 0.0
    m = link_pose(q_zero)  # palm at arm zero = M(wrist)
    r_arm_target = target_R @ m[:3, :3].T
    best = None
    for euler in _euler_xyz(r_arm_target):
        euler = _wrap(euler)
        cost = float(np.sum(_wrap(euler - q[3:6]) ** 2))
        if best is None or cost < best[0]:
            best = (cost, euler)
    euler = best[1]
    r_arm = rot_x(euler[0]) @ rot_y(euler[1]) @ rot_z(euler[2])
    q[3:6] = euler
    q[0:3] = target_pos - r_arm @ (m[:3, :3] @ local + m[:3, 3])
    lower, upper = _arm_limits()
    if np.any(q[ARM] < lower - 1e-9) or np.any(q[ARM] > upper + 1e-9):
        raise ValueError(f"palm target {target_pos.tolist()} needs arm joints {q[ARM].round(4).tolist()} "
                         f"outside the limits {lower.tolist()} .. {upper.tolist()}")
    p, r = palm_pose(q)
    reached = p + r @ local
    if np.linalg.norm(reached - target_pos) > _POS_TOL or rotation_error(r, target_R) > _ROT_TOL:
        q = _refine(q, target_pos, target_R, local)
    return q


@functools.lru_cache(maxsize=1)
def _arm_limits_cached() -> tuple[tuple[float, ...], tuple[float, ...]]:
    limits = default_spec().joint_limits()
    names = JOINT_NAMES[ARM]
    return tuple(limits[n][0] for n in names), tuple(limits[n][1] for n in names)


def _arm_limits() -> tuple[np.ndarray, np.ndarray]:
    lower, upper = _arm_limits_cached()
    return np.array(lower), np.array(upper)


def _refine(q: np.ndarray, target_pos: np.ndarray, target_R: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Numerical fallback: pytorch-kinematics PseudoInverseIK over the six arm joints."""
    import pytorch_kinematics as pk  # heavy (torch + its own kinematics): loaded on the first IK call

    chain = _chain()
    serial = pk.SerialChain(chain, PALM_LINK)
    n = len(serial.get_joint_parameter_names())
    target = np.eye(4)
    target[:3, :3] = target_R
    target[:3, 3] = target_pos - target_R @ local
    goal = pk.Transform3d(matrix=torch.as_tensor(target[None]), dtype=torch.float64)
    lim = serial.get_joint_limits()
    ik = pk.PseudoInverseIK(serial, max_iterations=200, num_retries=1,
                            retry_configs=torch.as_tensor(q[None, :n]),
                            joint_limits=torch.as_tensor(np.stack(lim, axis=1)), early_stopping_any_converged=True,
                            lr=0.5)
    sol = ik.solve(goal)
    out = q.copy()
    out[:n] = sol.solutions[0, 0].numpy()
    return out
