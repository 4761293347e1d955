"""Where the hand can still be for the rest of a plan episode (``HandReach``), so that a task can tell that a body
at rest is out of the hand's reach and will stay where it is (``PRLTaskEnv.failure_decided``).

The executor plans every stage's waypoint when the stage starts and ramps the joint targets towards it on a
straight line in joint space (a minimum-jerk profile only changes the timing; the grasp's per-joint closing
windows are the one exception, and the grasp is never in a path asked for here). Once the stages still to run
plan only from the previous waypoint (no ``pregrasp``, ``grasp`` or unplanned ``transport`` ahead, see
``Episode._remaining_path``), the joint targets of the rest of the episode are known: the measured joints now,
then each waypoint in turn. ``HandReach`` samples that path finely enough that no point of the hand moves more
than ``PATH_STEP`` between samples, puts each hand link's collision shapes (as capsules) at each sample with the
forward kinematics, and measures the smallest distance to a set of bodies.

What the hand really does differs from its targets: the drives lag, and a hand pushed onto a static prop (the
table, a rack, the board) stays on top of it while its target goes through it. The second is covered exactly:
a hand capsule below the top of the highest static prop is widened into a vertical column up to that top. The
first is covered by ``REACH_MARGIN``: a body counts as out of reach only if the sampled path stays farther than
that from it.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from envs import ik
from prl.geometry import box_capsules, segment_distance

REACH_MARGIN = 0.05
"""Clearance (m) the hand's remaining target path must keep from a body for the body to count as out of the hand's
reach: the drives' tracking error of a hand that holds nothing (bench/bench_decided.py measures it), plus
``PATH_STEP`` / 2 of sampling."""
PATH_STEP = 0.01
"""Largest displacement (m) of any point of the hand between two samples of the path."""
LEVERS = ((slice(0, 3), 1.0), (slice(3, 6), 0.45), (slice(6, 8), 0.30), (slice(8, 30), 0.12))
"""(joints, lever in m): an upper bound on how far a point of the hand moves per unit of each joint (m/m for the
arm's slides; for a revolute joint its largest distance to a point of the hand beyond it: the forearm's far end
from the arm's rotation centre, the fingertips from the wrist and from the knuckles)."""


def local_capsules(shape: Any) -> np.ndarray:
    """Capsules (n, 7) [a, b, radius] covering one PhysX collision shape, in the frame of the body it belongs to."""
    kind = type(shape).__name__
    if kind == "PhysxCollisionShapeBox":
        caps = box_capsules(np.asarray(shape.half_size, dtype=np.float64))
    elif kind in ("PhysxCollisionShapeCapsule", "PhysxCollisionShapeCylinder"):  # along the shape's X
        h = float(shape.half_length)
        caps = np.array([[-h, 0.0, 0.0, h, 0.0, 0.0, float(shape.radius)]])
    elif kind == "PhysxCollisionShapeSphere":
        caps = np.array([[0.0] * 6 + [float(shape.radius)]])
    elif kind == "PhysxCollisionShapeConvexMesh":
        v = np.asarray(shape.vertices, dtype=np.float64) * np.asarray(shape.scale, dtype=np.float64)
        lo, hi = v.min(axis=0), v.max(axis=0)
        caps = box_capsules((hi - lo) / 2)
        caps[:, :6] += np.tile((hi + lo) / 2, 2)
    else:
        raise TypeError(f"no capsule bound for a collision shape of type {kind}")
    m = np.asarray(shape.local_pose.to_transformation_matrix(), dtype=np.float64)
    return _moved(caps, m)


def _moved(caps: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Capsules (..., n, 7) moved by the 4x4 transform(s) ``m`` (..., 4, 4)."""
    r, t = m[..., None, :3, :3], m[..., None, :3, 3]
    out = np.empty(np.broadcast_shapes(caps.shape, m.shape[:-2] + caps.shape[-2:]))
    out[..., 0:3] = np.einsum("...ij,...j->...i", r, caps[..., 0:3]) + t
    out[..., 3:6] = np.einsum("...ij,...j->...i", r, caps[..., 3:6]) + t
    out[..., 6] = caps[..., 6]
    return out


def body_capsules(component: Any) -> np.ndarray:
    """Capsules (n, 7) covering a PhysX body's collision shapes where the body is now (world frame)."""
    m = np.asarray(component.entity_pose.to_transformation_matrix(), dtype=np.float64)
    return np.concatenate([_moved(local_capsules(s), m) for s in component.get_collision_shapes()])


def hand_capsules(env: Any, qs: np.ndarray, root: np.ndarray) -> np.ndarray:
    """Capsules (K * n, 7) covering the hand's collision shapes at each of the joint vectors ``qs`` (K, 30)
    (``JOINT_NAMES`` order; ``root``: the articulation root's 4x4 pose), from the forward kinematics."""
    links = [(link.name, link._objs[0]) for link in env.agent.robot.get_links()]
    links = [(name, c) for name, c in links if c.get_collision_shapes()]
    poses = ik.link_poses(qs, [name for name, _ in links], root=root)
    caps = [_moved(np.concatenate([local_capsules(s) for s in c.get_collision_shapes()]), poses[name])
            for name, c in links]
    return np.concatenate(caps, axis=1).reshape(-1, 7)


def capsule_clearance(a: np.ndarray, b: np.ndarray) -> float:
    """Smallest distance (m) between two sets of capsules (n, 7) and (m, 7); inf if either is empty.

    Exact, but the segments are compared only for the pairs whose bounding spheres come closer than the best
    distance between the segments' midpoints (an upper bound: the midpoints lie on the segments)."""
    if not len(a) or not len(b):
        return float("inf")
    ca, cb = (a[:, 0:3] + a[:, 3:6]) / 2, (b[:, 0:3] + b[:, 3:6]) / 2
    ra = a[:, 6] + np.linalg.norm(a[:, 3:6] - a[:, 0:3], axis=1) / 2
    rb = b[:, 6] + np.linalg.norm(b[:, 3:6] - b[:, 0:3], axis=1) / 2
    centres = np.linalg.norm(ca[:, None] - cb[None], axis=2)
    best = float(np.min(centres - a[:, None, 6] - b[None, :, 6]))
    i, j = np.nonzero(centres - ra[:, None] - rb[None] < best)
    if not len(i):
        return best
    gaps = segment_distance(a[i, 0:3], a[i, 3:6], b[j, 0:3], b[j, 3:6]) - a[i, 6] - b[j, 6]
    return min(best, float(np.min(gaps)))


def moving_bodies(env: Any) -> list[Any]:
    """The PhysX bodies of ``env``'s scene that can move, the hand aside: its dynamic actors (the tool, debris
    cubes) and the links of its other articulations but a fixed root (the nail's head, the cap, the tweezers)."""
    bodies = [b for actor in env.scene.actors.values() if actor.px_body_type != "static" for b in actor._bodies]
    hand = env.agent.robot if env.agent is not None else None
    for articulation in env.scene.articulations.values():
        if articulation is hand:
            continue
        links = articulation._objs[0].get_links()
        bodies += [link for i, link in enumerate(links) if i > 0 or link.joint.type != "fixed"]
    return bodies


def static_top(env: Any) -> float:
    """Height (m) of the highest point of the scene's static props (the table top, racks, the board, fixed
    articulation roots such as the bottle's holder); planes (the floor) do not count."""
    comps = [b for actor in env.scene.actors.values() if actor.px_body_type == "static" for b in actor._bodies]
    hand = env.agent.robot if env.agent is not None else None
    comps += [a._objs[0].get_links()[0] for a in env.scene.articulations.values()
              if a is not hand and a._objs[0].get_links()[0].joint.type == "fixed"]
    top = 0.0
    for comp in comps:
        shapes = [s for s in comp.get_collision_shapes() if type(s).__name__ != "PhysxCollisionShapePlane"]
        if not shapes:
            continue
        m = np.asarray(comp.entity_pose.to_transformation_matrix(), dtype=np.float64)
        for shape in shapes:
            if type(shape).__name__ == "PhysxCollisionShapeBox":  # exact: a capsule bound of a wide box is tall
                local = np.asarray(shape.local_pose.to_transformation_matrix(), dtype=np.float64)
                w = m @ local
                top = max(top, float(w[2, 3] + np.abs(w[2, :3]) @ np.asarray(shape.half_size, dtype=np.float64)))
            else:
                caps = _moved(local_capsules(shape), m)
                top = max(top, float(np.max(np.maximum(caps[:, 2], caps[:, 5]) + caps[:, 6])))
    return top


def sample_path(waypoints: np.ndarray, step: float = PATH_STEP) -> np.ndarray:
    """Joint vectors (K, 30) along the piecewise-linear joint path through ``waypoints`` (n, 30), close enough
    that no point of the hand moves more than ``step`` between two of them (``LEVERS``)."""
    waypoints = np.asarray(waypoints, dtype=np.float64)
    out = [waypoints[:1]]
    for a, b in itertools.pairwise(waypoints):
        move = sum(float(np.abs(b[joints] - a[joints]).sum()) * lever for joints, lever in LEVERS)
        n = max(1, int(np.ceil(move / step)))
        s = np.arange(1, n + 1)[:, None] / n
        out.append(a + (b - a) * s)
    return np.concatenate(out)


class HandReach:
    """The hand's remaining path in one plan episode, asked whether it stays clear of some bodies.

    ``path`` is called on the first question only (the forward kinematics of the sampled path cost a few ms) and
    returns the waypoints (n, 30) of the joint path still to run, starting with the measured joints, or None
    when the rest of the episode is not planned yet (then nothing is ever out of reach).
    """

    def __init__(self, env: Any, path: Callable[[], np.ndarray | None], root: np.ndarray) -> None:
        self.env = env
        self._path = path
        self.root = np.asarray(root, dtype=np.float64)
        self._hand: np.ndarray | None = None
        self._known: bool | None = None

    def _hand_capsules(self) -> np.ndarray | None:
        """(K * shapes, 7) capsules of the hand's collision shapes at every sample of the path; None if unknown."""
        if self._known is None:
            waypoints = self._path()
            self._known = waypoints is not None
            if self._known:
                caps = hand_capsules(self.env, sample_path(waypoints), self.root)
                self._hand = _columns(caps, static_top(self.env))
        return self._hand

    def clearance(self, bodies: Sequence[Any]) -> float:
        """Smallest distance (m) between the hand's remaining path and the PhysX ``bodies`` where they are now; -inf
        when the path is not known yet, inf for no body."""
        hand = self._hand_capsules()
        if hand is None:
            return -np.inf
        return capsule_clearance(hand, np.concatenate([body_capsules(b) for b in bodies])) if bodies else np.inf

    def clear_of(self, bodies: Sequence[Any], margin: float = REACH_MARGIN) -> bool:
        """Whether the hand's remaining path stays farther than ``margin`` from every one of ``bodies``."""
        return self.clearance(bodies) > margin


def _columns(caps: np.ndarray, top: float) -> np.ndarray:
    """The capsules (n, 7), each reaching below ``top`` replaced by a vertical column from its centre up to
    ``top`` as wide as the capsule is long: where a static prop under a target stops the hand."""
    low = np.minimum(caps[:, 2], caps[:, 5]) - caps[:, 6] < top
    if not low.any():
        return caps
    out = caps.copy()
    centre = (caps[low, 0:3] + caps[low, 3:6]) / 2
    half = np.linalg.norm(caps[low, 3:6] - caps[low, 0:3], axis=1) / 2
    out[low, 0:3] = centre
    out[low, 3:6] = centre
    out[low, 5] = np.maximum(centre[:, 2], top)
    out[low, 6] = caps[low, 6] + half
    return out
