"""Plan executor: a Representation-Space plan vector -> joint drive targets -> simulated episode.

One plan episode (paper Fig 2) runs ``n_frames`` physics frames (``EPISODE_SECONDS`` = 3 s of
simulated time at the task's physics rate) through the stages its task declares
(``PRLTaskEnv.stages``, a :class:`StageSpec`: which stages run, their time shares, where T_fv meets
the object, what follows the motion). The executor knows these stages, in this order:

0. ``pregrasp``  from home, put the chosen palm anchor (a2) on the centre line of T_gv, a
   few cm out along the palm normal, with the palm rotated relative to T_gv by Rx(a0) Rz(a1);
   fingers open, pre-shaped for the pattern.
1. ``approach``  move along the palm normal until the anchor is at the pattern's gap from the
   tool's surface (a power grasp presses the palm onto it).
2. ``grasp``     close the fingers into the pattern's posture (a3, :data:`GRASP_POSTURES`), joint
   groups in the posture's closing order. The targets lie past the tool, so the PD drives press
   the phalanges on it; the tool is then held by contact and friction only.
3. ``lift``      lift the hand (and, if the grasp holds, the tool) straight up.
4. ``transport`` move above the object, rotating the hand so that the object's Z axis is
   aligned with the chosen T_fv axis (a5).
5. ``place``     bring T_fv's leading face to ~3 cm from the object, on the side the task
   declares (``fv_approach``), at the start of the motion.
6. ``motion``    the kinematic motion (a4): a fast joint-space displacement along the
   motion's template (wrist WRJ1 / WRJ2 swing, arm translation along X / Y / Z, arm rotation
   about the palm centre, finger squeeze). Without a place stage it acts from the grasp.
7. ``post_lift`` lift the hand again after the motion (e.g. tweezers carrying a cube up).

Required: pregrasp, approach, grasp, motion. The hammer runs 0-6 (pick up -> carry -> strike).

The transport/place targets are planned at the end of the lift from the *measured* tool pose
in the palm (what a robot with object tracking would do); the place pose is chosen so that
the motion's displacement would bring T_fv's leading face onto the object. Arm and wrist
targets come from ``envs/ik.py``. Targets are ramped between waypoints with a minimum-jerk
profile and written to the PhysX joint drives only when they change; the scene is stepped frame by
frame with ``env.step_physics()`` (``scene.step()`` and the task's per-frame watch).

Physical honesty: the executor never sets a pose, velocity or joint state of the tool or the
object, adds no joint or constraint, and the outcome is the task's ``evaluate()`` of the
simulated state. NaN / blow-ups end the episode as a failure.

``python -m envs.executor --task hammer --plan 0,3,2,0,0,1 --scenes 50`` reports success
rates (and ``--random-plans N`` those of uniformly random plans).
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from prl.constants import EPISODE_SECONDS, JOINT_NAMES, N_ANCHORS, N_JOINTS, N_SENSORS, RECORD_HZ
from prl.demo import X_MANIP_DIM, X_MANIP_LAYOUT, X_MANIP_SAMPLES, x_manip_from_samples
from prl.geometry import rot_x, rot_z
from prl.labels import tool_object_axis

STAGES: tuple[str, ...] = ("pregrasp", "approach", "grasp", "lift", "transport", "place", "motion", "post_lift")
"""Every stage the executor knows, in execution order; ``EpisodeResult.stage`` holds indices into this
tuple. A task runs the subsequence its ``StageSpec`` declares (the others get 0 frames)."""

REQUIRED_STAGES: tuple[str, ...] = ("pregrasp", "approach", "grasp", "motion")
"""Stages every task runs: a plan always grasps its tool and performs its kinematic motion."""

FAULTS: tuple[str, ...] = ("unreachable", "blowup")
"""Why the executor may end a valid plan as a failure on its own (``EpisodeResult.fault``):
``unreachable`` - a stage found no joint target for its waypoint (no IK solution, no place pose, a
non-finite target) and held still, so the plan then failed physically; ``blowup`` - the simulated
state became non-finite or ran away (faster than ``ExecutorConfig.blowup_speed``), and stepping stopped.
A valid plan never raises: every such case is a failed ``EpisodeResult`` with its reason in ``notes``."""

PLANNING_ERRORS: tuple[type[Exception], ...] = (ValueError, ArithmeticError, np.linalg.LinAlgError)
"""What planning a stage's waypoint may raise on a hard scene (IK without a solution, a degenerate
geometry); each makes the stage hold still with fault ``unreachable``. Anything else is a bug and raises."""


@dataclass(frozen=True)
class StageSpec:
    """What a task needs from the generic executor, declared as data on the task class (``stages``).

    The executor has no per-task branches: which post-grasp stages run, where T_fv meets the object
    and what follows the motion all come from here.
    """

    shares: tuple[tuple[str, float], ...]
    """(stage, share of the episode's frames) for each stage the task runs, in ``STAGES`` order.
    Stages not listed are skipped. Without ``lift``/``transport``/``place`` the tool stays where it
    was grasped (a cap on its bottle) and the motion starts from the grasp."""
    fv_approach: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """Unit direction, in the object's frame, from which T_fv's leading face comes onto the object at
    the end of ``place`` (the hammer's head: from above, the object's +Z)."""
    post_lift_height: float = 0.0
    """Lift (m) of the hand in ``post_lift``, after the motion (tweezers carrying the cube up)."""
    motion_dir: tuple[float, float, float] | None = None
    """Unit direction, in the object's frame, in which the motion must carry T_fv; of a motion's two
    signs the place stage takes the one whose place pose lies farthest back along it. None: onto the
    object, ``-fv_approach`` (the hammer's strike comes down; a sweep declares the way to its zone)."""
    motion_scale: float = 1.0
    """Factor on ``MOTION_AMPLITUDES`` (a sweep pushes farther than a strike swings)."""
    motion_s: float | None = None
    """Seconds over which the motion's displacement is ramped; None: the executor's fast strike
    (``ExecutorConfig.strike_ramp_s``). A sweep pushes slowly so the debris slides instead of flying."""

    def __post_init__(self) -> None:
        names = [name for name, _ in self.shares]
        unknown = [n for n in names if n not in STAGES]
        if unknown:
            raise ValueError(f"unknown stage(s) {unknown}; known: {list(STAGES)}")
        if names != sorted(names, key=STAGES.index) or len(set(names)) != len(names):
            raise ValueError(f"stages must be listed once each in execution order {list(STAGES)}, got {names}")
        missing = [n for n in REQUIRED_STAGES if n not in names]
        if missing:
            raise ValueError(f"every task runs {list(REQUIRED_STAGES)}; missing {missing}")
        if "place" in names and "transport" not in names:
            raise ValueError("stage 'place' needs 'transport' (the place pose is planned when the transport starts)")
        bad = [(n, v) for n, v in self.shares if not (isinstance(v, (int, float)) and v > 0)]
        if bad:
            raise ValueError(f"stage shares must be positive numbers, got {bad}")
        if ("post_lift" in names) != (self.post_lift_height > 0):
            raise ValueError(f"post_lift_height must be > 0 exactly when 'post_lift' runs, got {self.post_lift_height!r}")
        if abs(float(np.linalg.norm(self.fv_approach)) - 1.0) > 1e-6:
            raise ValueError(f"fv_approach must be a unit vector, got {self.fv_approach!r}")
        if self.motion_dir is not None and abs(float(np.linalg.norm(self.motion_dir)) - 1.0) > 1e-6:
            raise ValueError(f"motion_dir must be a unit vector or None, got {self.motion_dir!r}")
        if not (isinstance(self.motion_scale, (int, float)) and self.motion_scale > 0):
            raise ValueError(f"motion_scale must be > 0, got {self.motion_scale!r}")
        if self.motion_s is not None and not (isinstance(self.motion_s, (int, float)) and self.motion_s > 0):
            raise ValueError(f"motion_s must be > 0 s or None, got {self.motion_s!r}")

    @property
    def push(self) -> np.ndarray:
        """``motion_dir`` resolved (object frame)."""
        if self.motion_dir is None:
            return -np.asarray(self.fv_approach, dtype=np.float64)
        return np.asarray(self.motion_dir, dtype=np.float64)

    def runs(self, stage: str) -> bool:
        """Whether the task runs ``stage``."""
        return any(name == stage for name, _ in self.shares)

    def stage_frames(self, n_frames: int) -> np.ndarray:
        """Frames per stage, ``STAGES`` order (0 for stages not run), summing to ``n_frames``."""
        share = dict(self.shares)
        f = np.array([share.get(name, 0.0) for name in STAGES], dtype=np.float64)
        bounds = np.round(np.cumsum(f / f.sum()) * n_frames).astype(int)
        return np.diff(np.concatenate([[0], bounds]))

_J = {name: i for i, name in enumerate(JOINT_NAMES)}
FINGER = slice(8, 30)


def _posture(**values: float) -> np.ndarray:
    """A (22,) finger posture from joint-name keyword values (others 0)."""
    q = np.zeros(N_JOINTS)
    for name, value in values.items():
        q[_J[name]] = value
    return q[FINGER].copy()


def _four(j3: float, j2: float, j1: float) -> dict[str, float]:
    """The same J3 / J2 / J1 flexion on the four fingers (for :func:`_posture`)."""
    return {f"{f}J{j}": v for f in ("FF", "MF", "RF", "LF") for j, v in ((3, j3), (2, j2), (1, j1))}


@dataclass(frozen=True)
class GraspPosture:
    """How the hand takes one grasp pattern: finger targets, closing order and how close the palm comes."""

    open: np.ndarray
    """(22,) finger targets (``JOINT_NAMES[8:]`` order) of the pre-shape, held from the pre-grasp on."""
    closed: np.ndarray
    """(22,) finger targets at the end of the grasp; they lie past the object, so the PD drives keep
    pressing the phalanges on it and the tool is held by contact and friction only."""
    gap: float
    """Anchor distance (m) from T_gv's surface along the palm normal at the end of the approach
    (<= 0: the palm is pressed onto the tool, as in a power grasp)."""
    closing: tuple[tuple[str, float, float], ...] = ()
    """(joint group, start, end): the part of the grasp stage over which that group's targets ramp
    (others: the whole stage). Groups: "J4".."J1" of the four fingers (LFJ5 goes with "J3"), "TH" the
    thumb."""

    def windows(self) -> tuple[np.ndarray, np.ndarray]:
        """(start, end) fractions of the grasp stage per joint, (30,) each, ``JOINT_NAMES`` order."""
        start, end = np.zeros(N_JOINTS), np.ones(N_JOINTS)
        for group, a, b in self.closing:
            if not 0.0 <= a < b <= 1.0:
                raise ValueError(f"closing window of {group} must satisfy 0 <= start < end <= 1, got {(a, b)}")
            for i in range(FINGER.start, N_JOINTS):
                name = JOINT_NAMES[i]
                thumb = name.startswith("TH")
                if (group == "TH" and thumb) or (not thumb and (name[2:] == group or (group == "J3" and name == "LFJ5"))):
                    start[i], end[i] = a, b
        return start, end


#: The grasp posture of each catalogue pattern (``assets/plb.yaml`` ``grasp_patterns``). Each one, closed
#: on the kind of object it is meant for, touches the sensors its catalogue vector lists (checked on the
#: reference objects of ``envs/tasks/grasp_probe.py`` by ``tests/test_grasp_patterns.py``).
GRASP_POSTURES: dict[str, GraspPosture] = {
    # power grasp: the thumb is first turned down towards the wrist, out of the palm plane (lying in it, it
    # sticks 8 mm out of the palm face and held the handle off the palm), the palm is pressed onto the
    # handle, the knuckles flex, then the middle and last joints curl the fingertips in behind it and the
    # thumb closes under it. Contacts: the palm (or, with the handle under the knuckles, the proximal
    # phalanges) and the fingertips; the 3.2 cm handle fits inside the finger loop without touching the
    # middle phalanges (catalogue note in assets/plb.yaml).
    "medium_wrap": GraspPosture(
        open=_posture(**_four(0.0, 0.0, 0.0), THJ5=-1.0, THJ4=1.2),
        closed=_posture(**_four(1.57, 1.57, 1.57), THJ5=0.6, THJ4=1.2, THJ2=0.6, THJ1=1.2),
        gap=-0.002,
        closing=(("J3", 0.0, 0.4), ("J2", 0.3, 0.8), ("J1", 0.3, 0.8), ("TH", 0.5, 1.0)),
    ),
    # extended fingers: only the knuckles flex, so the straight fingers' middle pads lie on the face (with
    # the palm tilted by a0 to the face's slant); then the thumb swings in from the wrist side against the
    # other face. No palm contact.
    "parallel_extension": GraspPosture(
        open=_posture(**_four(0.0, 0.0, 0.0), THJ5=-1.0, THJ4=1.2),
        closed=_posture(**_four(1.57, 0.0, 0.0), THJ5=0.6, THJ4=1.2),
        gap=0.015,
        closing=(("J3", 0.0, 0.4), ("J2", 0.0, 0.4), ("TH", 0.4, 1.0)),
    ),
    # index and thumb only: the index curls its pad down onto the object, the thumb swings in from the
    # wrist side under it; the object hangs a few cm below the palm (large gap), clear of the palm.
    "palmar_pinch": GraspPosture(
        open=_posture(**_four(0.0, 0.0, 0.0), THJ5=-1.0, THJ4=1.2),
        closed=_posture(FFJ3=1.3, FFJ2=1.3, FFJ1=0.9, THJ5=1.0, THJ4=1.2, THJ2=0.4, THJ1=0.6),
        gap=0.05,
        closing=(("J3", 0.0, 0.6), ("J2", 0.0, 0.6), ("J1", 0.0, 0.6), ("TH", 0.3, 1.0)),
    ),
    # fingertips spread round a disk below the palm, the thumb opposing them from the wrist side
    "precision_disk": GraspPosture(
        open=_posture(**_four(0.0, 0.0, 0.0), THJ5=-1.0, THJ4=1.2),
        closed=_posture(FFJ4=-0.3, MFJ4=-0.1, RFJ4=-0.1, LFJ4=-0.3, **_four(1.2, 1.2, 0.9),
                        THJ5=1.0, THJ4=1.2, THJ2=0.4, THJ1=0.6),
        gap=0.045,
        closing=(("TH", 0.3, 1.0),),
    ),
}


#: Amplitude of each kinematic motion along its catalogue template (``assets/plb.yaml``
#: ``motion_templates``, the "+" one): rad for joint rotations, m for arm translations. The sign
#: is chosen per episode (approach the object from above where the motion allows).
MOTION_AMPLITUDES: dict[str, float] = {
    "wrist_horizontal": 0.45, "wrist_vertical": 0.45,
    "arm_linear_x": 0.035, "arm_linear_y": 0.035, "arm_linear_z": 0.035,
    "arm_rotate_palm": 0.45, "finger_squeeze": 0.3,
}
#: Fraction of the motion amplitude driven past the planned contact (the drives push through).
MOTION_OVERSHOOT = 0.6



@dataclass(frozen=True)
class ExecutorConfig:
    """How a plan is executed. Durations are in seconds; frame counts left at None follow from them at the
    task's physics rate when a ``PlanExecutor`` is made (its ``config`` holds the resolved numbers)."""

    n_frames: int | None = None
    """Physics frames per plan episode; None: ``episode_s`` at the task's physics rate (``EPISODE_FRAMES``
    at the pipeline's ``SIM_FREQ``). The paper's "1500 frames" is an Isaac Sim count with an unstated step;
    what is kept is the simulated duration."""
    episode_s: float = EPISODE_SECONDS
    """Simulated duration of a plan episode (s) when ``n_frames`` is None."""
    record_every: int | None = None
    """Record one frame every this many physics frames; None: ``RECORD_HZ`` records per second."""
    pregrasp_clearance: float = 0.05
    """Anchor distance (m) from the handle surface along the palm normal before the approach."""
    lift_height: float = 0.10
    """Lift (m) of the hand after grasping."""
    hover_height: float = 0.06
    """Height (m) above the place pose at the end of the transport."""
    strike_settle_frac: float = 0.15
    """Part of the motion stage spent holding still before the motion."""
    strike_ramp_frames: int | None = None
    """Frames over which the motion's displacement is ramped (fast strike); None: ``strike_ramp_s``."""
    strike_ramp_s: float = 0.08
    blowup_speed: float = 50.0
    """A tool or hand link faster than this (m/s) counts as a simulation blow-up."""
    observe_frames: int | None = None
    """Physics frames of the observation phase that precedes the plan (hand held at home, tool and
    object settling; x_manip is sampled from it, see :meth:`PlanExecutor.observe`); None: ``observe_s``."""
    observe_s: float = 0.08

    def __post_init__(self) -> None:
        if self.n_frames is not None and self.n_frames < 100:
            raise ValueError(f"n_frames must be >= 100, got {self.n_frames!r}")
        if self.observe_frames is not None and self.observe_frames < X_MANIP_SAMPLES:
            raise ValueError(f"observe_frames must be >= {X_MANIP_SAMPLES}, got {self.observe_frames!r}")
        if self.record_every is not None and self.record_every < 1:
            raise ValueError(f"record_every must be >= 1, got {self.record_every!r}")
        for name in ("episode_s", "strike_ramp_s", "observe_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0 s, got {getattr(self, name)!r}")

    def at_rate(self, sim_freq: float) -> ExecutorConfig:
        """This config with every frame count fixed for a physics rate of ``sim_freq`` Hz."""
        def frames(given: int | None, seconds: float) -> int:
            return int(given) if given is not None else max(1, int(round(seconds * sim_freq)))

        if self.record_every is None and sim_freq % RECORD_HZ:
            raise ValueError(f"the physics rate {sim_freq} Hz is not a multiple of the recording rate {RECORD_HZ} Hz")

        return replace(
            self,
            n_frames=frames(self.n_frames, self.episode_s),
            record_every=frames(self.record_every, 1.0 / RECORD_HZ),
            strike_ramp_frames=frames(self.strike_ramp_frames, self.strike_ramp_s),
            observe_frames=max(X_MANIP_SAMPLES, frames(self.observe_frames, self.observe_s)),
        )


@dataclass
class EpisodeResult:
    """One executed plan: outcome from the simulated state and the recorded trajectory."""

    plan: np.ndarray
    """(6,) int64 plan vector."""
    outcome: dict[str, Any]
    """The task's ``evaluate()`` at the end (plain Python values), plus ``blowup``."""
    success: bool
    """``outcome["success"]`` and no blow-up."""
    frame: np.ndarray
    """(T,) physics frame index of each record."""
    stage: np.ndarray
    """(T,) stage index (into ``STAGES``) of each record."""
    qpos: np.ndarray
    """(T, 30) joint positions, ``JOINT_NAMES`` order."""
    qvel: np.ndarray
    """(T, 30) joint velocities."""
    target: np.ndarray
    """(T, 30) joint drive targets."""
    force: np.ndarray
    """(T, 17) contact force per sensor (N)."""
    contact_pos: np.ndarray
    """(T, 17, 3) contact position per sensor (world, m)."""
    contact_normal: np.ndarray
    """(T, 17, 3) contact normal per sensor (world, unit)."""
    palm_pose: np.ndarray
    """(T, 7) palm link pose [x, y, z, qw, qx, qy, qz]."""
    tool_pose: np.ndarray
    """(T, 7) tool actor pose."""
    object_pose: np.ndarray
    """(T, 7) object frame pose (``object_frame_world``)."""
    anchors_at_grasp: np.ndarray
    """(6, 3) world positions of the palm anchors at the end of the grasp stage."""
    gv_at_grasp: tuple[np.ndarray, np.ndarray, np.ndarray]
    """T_gv (center, half_extents, R) at the end of the grasp stage."""
    stage_frames: np.ndarray
    """(7,) physics frames per stage."""
    wall_time_s: float
    """Wall time of the stepping loop (s)."""
    physics_time_s: float = 0.0
    """Part of ``wall_time_s`` spent inside ``scene.step()`` (the raw PhysX cost of this episode)."""
    fps: float = 0.0
    """Physics frames per second of the loop (incl. target updates and recording)."""
    notes: list[str] = field(default_factory=list)
    """Planner notes (e.g. an unreachable target replaced by the nearest reachable one)."""
    fault: str = ""
    """Why the executor, not physics alone, ended the plan: ``""`` (nothing went wrong in planning or
    simulation), or one of ``FAULTS``; the details are in ``notes``."""
    x_manip: np.ndarray = field(default_factory=lambda: np.zeros(X_MANIP_DIM, np.float32))
    """(784,) features of the observation phase before the plan acted (``prl.demo`` layout)."""


# ----------------------------------------------------------------------------- geometry
def _pose7(p: np.ndarray, r: np.ndarray) -> np.ndarray:
    from envs.tasks.base import pose_from_matrix

    return _sapien_pose7(pose_from_matrix(p, r))


def _sapien_pose7(pose: Any) -> np.ndarray:
    return np.concatenate([np.asarray(pose.p, dtype=np.float64), np.asarray(pose.q, dtype=np.float64)])


def _pose_matrix(pose: Any) -> np.ndarray:
    return np.asarray(pose.to_transformation_matrix(), dtype=np.float64)


def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector ``a`` onto unit vector ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1 + 1e-9:  # opposite: rotate pi about any axis perpendicular to a
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def _min_jerk(s: np.ndarray | float) -> np.ndarray | float:
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s * s)


# ----------------------------------------------------------------------------- executor
class PlanExecutor:
    """Executes plan vectors on a PRL task environment (``env.unwrapped`` of ``make_env``)."""

    def __init__(self, env: Any, config: ExecutorConfig | None = None) -> None:
        self.env = env.unwrapped if hasattr(env, "unwrapped") else env
        self.sim_freq = float(self.env.sim_freq)
        """Physics steps per second of the task's scene."""
        self.config = (config or ExecutorConfig()).at_rate(self.sim_freq)
        """The config with its frame counts fixed for ``sim_freq``."""
        from prl import plb as plb_module

        self.plb = plb_module.load_plb()
        self._observation: np.ndarray | None = None

    # ------------------------------------------------------------------ public
    def validate(self, plan: Any) -> np.ndarray:
        """The plan as an int64 (6,) vector; ``ValueError`` naming the bad value otherwise."""
        return self.plb.validate_plan(plan)

    def run(self, plan: Any, seed: int | None = None,
            on_stage_end: Callable[[str, int], None] | None = None) -> EpisodeResult:
        """Reset the task with ``seed`` (None: keep the current scene) and execute ``plan``.

        ``on_stage_end(stage_name, frame)``, if given, is called once per stage (``STAGES`` names,
        in order) right after the stage's last physics frame was stepped and recorded, with that
        frame's index; the simulated state is then the one at the end of the stage (e.g. to
        render a picture of it). The hook must not change the simulation. After a blow-up it is
        called for the stage that blew up (with the last stepped frame) and not for the stages
        that were never reached. It is invoked only at stage boundaries, never per frame; None
        (the default) costs nothing. Time spent in the hook is not counted in ``wall_time_s``/``fps``.
        """
        plan = self.validate(plan)
        if seed is not None:
            self.env.reset(seed=int(seed))
            self._observation = None
        observation = self._observation if self._observation is not None else self.observe()
        self._observation = None
        result = _Episode(self, plan).run(on_stage_end)
        if not np.all(np.isfinite(observation)):  # the scene blew up before the plan acted
            observation = np.nan_to_num(observation, nan=0.0, posinf=0.0, neginf=0.0)
            result.notes.append("blowup: non-finite state in the observation phase (x_manip zeroed)")
            result.fault, result.success = "blowup", False
            result.outcome.update(success=False, fail=True, blowup=True)
        result.x_manip = observation
        return result

    def observe(self, seed: int | None = None) -> np.ndarray:
        """Reset with ``seed`` (None: keep the scene) and run the observation phase; return x_manip.

        The hand's drives hold its current (home) pose for ``observe_frames`` physics frames while
        the tool and object settle; ``X_MANIP_SAMPLES`` evenly spaced states are taken (layout
        ``prl.demo.X_MANIP_LAYOUT``). Nothing here depends on a plan, so a policy can choose the plan
        from these features: call ``observe(seed)``, pick a plan, then ``run(plan)`` (no seed), which
        continues from the observed state. ``run(plan, seed)`` observes by itself.
        """
        if seed is not None:
            self.env.reset(seed=int(seed))
        self._observation = _observe(self.env, self.config.observe_frames)
        return self._observation.copy()


def _observe(env: Any, n_frames: int) -> np.ndarray:
    """Hold the hand's drive targets at its current pose for ``n_frames`` frames; sample x_manip."""
    from envs.sensors import ContactSensors

    agent = env.agent
    art = agent.robot._objs[0]
    perm = agent.joint_perm
    joints = art.get_active_joints()
    qpos = np.asarray(art.get_qpos(), dtype=np.float64)
    for j, q in zip(joints, qpos):
        j.set_drive_target(float(q))
    palm, tool = agent.palm_link._objs[0], env.tool._bodies[0]
    sensors = ContactSensors(env.scene, agent.sensor_links, exclude=agent.robot)
    picks = set(np.round(np.linspace(0, n_frames - 1, X_MANIP_SAMPLES)).astype(int).tolist())
    samples: dict[str, list[np.ndarray]] = {name: [] for name, _ in X_MANIP_LAYOUT}
    for frame in range(n_frames):
        env.step_physics()
        if frame in picks:
            samples["qpos"].append(np.asarray(art.get_qpos(), dtype=np.float64)[perm])
            samples["qvel"].append(np.asarray(art.get_qvel(), dtype=np.float64)[perm])
            samples["force"].append(sensors.read()[0])
            samples["palm_pose"].append(_sapien_pose7(palm.get_entity_pose()))
            samples["tool_pose"].append(_sapien_pose7(tool.get_entity_pose()))
            samples["object_pose"].append(_pose7(*env.object_frame_world()))
    return x_manip_from_samples({name: np.stack(v) for name, v in samples.items()})


class _Episode:
    """State of one plan execution."""

    def __init__(self, executor: PlanExecutor, plan: np.ndarray) -> None:
        from envs import ik
        from envs.hand_model import palm_anchors
        from envs.sensors import ContactSensors

        self.ik = ik
        self.cfg = executor.config
        self.env = executor.env
        self.plan = plan
        self.plb = executor.plb
        names = executor.plb.decode(plan)
        self.rot_x = np.deg2rad(float(names[0]))
        self.rot_z = np.deg2rad(float(names[1]))
        self.anchor = int(names[2])
        self.pattern = str(names[3])
        self.motion = str(names[4])
        self.fv_axis = str(names[5])
        self.anchor_local = palm_anchors()[self.anchor]
        agent = self.env.agent
        self.agent = agent
        self.art = agent.robot._objs[0]
        self.joints = self.art.get_active_joints()
        self.perm = agent.joint_perm
        self.palm_body = agent.palm_link._objs[0]
        self.tool_body = self.env.tool._bodies[0]
        self.sensors = ContactSensors(self.env.scene, agent.sensor_links, exclude=agent.robot)
        self.spec: StageSpec = type(self.env).stages
        self.sim_freq = executor.sim_freq
        self._ahead: dict[str, np.ndarray] = {}
        """Targets planned ahead for a later stage (approach by the pregrasp, place and motion by the transport)."""
        self.notes: list[str] = []
        self.fault = ""
        self.current_target = self._qpos()
        self.root = _pose_matrix(self.art.get_root_pose())

    # ------------------------------------------------------------------ state
    def _qpos(self) -> np.ndarray:
        return np.asarray(self.art.get_qpos(), dtype=np.float64)[self.perm]

    def _qvel(self) -> np.ndarray:
        return np.asarray(self.art.get_qvel(), dtype=np.float64)[self.perm]

    def _write_targets(self, q: np.ndarray) -> None:
        for i in range(N_JOINTS):
            self.joints[self.perm[i]].set_drive_target(float(q[i]))

    def _solve(self, pos: np.ndarray, rot: np.ndarray, q_ref: np.ndarray, point: np.ndarray | None = None) -> np.ndarray:
        return self.ik.solve_palm_pose(pos, rot, q_ref, point=point, root=self.root)

    # ------------------------------------------------------------------ planning
    def _grasp_frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """(gv centre, palm rotation at grasp, palm normal n (world, out of the palm front), radius along n)."""
        center, half, r_gv = self.env.tool_gv_world()
        r_palm = r_gv @ rot_x(self.rot_x) @ rot_z(self.rot_z)
        out = r_palm[:, 1]  # +Y_palm: from the front face back into the hand; the handle lies along -Y_palm
        extent = float(np.sum(np.abs(r_gv.T @ out) * half))  # support of T_gv along the palm normal
        return center, r_palm, out, extent

    def plan_pregrasp(self, q_now: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        center, r_palm, out, extent = self._grasp_frame()
        posture = GRASP_POSTURES[self.pattern]
        open_q = posture.open
        ref = q_now.copy()
        ref[FINGER] = open_q
        ref[6:8] = 0.0
        far = self._solve(center + out * (extent + self.cfg.pregrasp_clearance), r_palm, ref, self.anchor_local)
        near = self._solve(center + out * (extent + posture.gap), r_palm, ref, self.anchor_local)
        return far, near

    def plan_grasp(self, q_near: np.ndarray) -> np.ndarray:
        q = q_near.copy()
        q[FINGER] = GRASP_POSTURES[self.pattern].closed
        return q

    def plan_lift(self, q_grasp: np.ndarray) -> np.ndarray:
        q = q_grasp.copy()
        q[_J["ARTz"]] += self.cfg.lift_height
        return q

    def _motion_vector(self) -> np.ndarray:
        """Joint displacement of the motion: its first catalogue template times its amplitude."""
        first = int(np.argmax(self.plb.template_to_motion == self.plan[4]))
        return self.plb.template_matrix()[first] * MOTION_AMPLITUDES[self.motion] * self.spec.motion_scale

    def plan_place(self, q_target_now: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(hover, place, strike) joint targets from the measured tool-in-palm transform."""
        palm_w = _pose_matrix(self.palm_body.get_entity_pose())
        tool_w = _pose_matrix(self.tool_body.get_entity_pose())
        tool_in_palm = np.linalg.inv(palm_w) @ tool_w
        fv_center_local, fv_half = (np.asarray(x, dtype=np.float64) for x in self.env.tool_fv_local)
        obj_p, obj_r = self.env.object_frame_world()
        z_obj = obj_r[:, 2]
        u = tool_object_axis(self.fv_axis)
        r_tool = tool_w[:3, :3]
        axis_w = r_tool @ u
        target_dir = z_obj if np.dot(axis_w, z_obj) >= 0 else -z_obj
        r_new = _min_rotation(axis_w, target_dir) @ r_tool
        # the side T_fv comes from (the task's ``fv_approach``, object frame), and T_fv's leading point
        # towards the object: the box support along -approach
        approach = obj_r @ np.asarray(self.spec.fv_approach, dtype=np.float64)
        d_local = r_new.T @ (-approach)
        support = float(np.sum(np.abs(d_local) * fv_half))
        fv_center_w_new_rel = r_new @ fv_center_local
        # tool pose at contact: T_fv's leading face on the object, centred on it
        p_tool = obj_p + approach * support - fv_center_w_new_rel
        t_tool = np.eye(4)
        t_tool[:3, :3] = r_new
        t_tool[:3, 3] = p_tool
        t_palm = t_tool @ np.linalg.inv(tool_in_palm)
        motion = self._motion_vector()
        best = None
        for sign in (1.0, -1.0):
            ref = q_target_now.copy()
            # the contact configuration with the motion completed, the place one before it
            contact_ref = ref.copy()
            if self.motion in ("wrist_horizontal", "wrist_vertical"):
                contact_ref[6:8] = 0.0
                contact_ref += sign * motion * 0.5
                contact_ref[6:8] = np.clip(contact_ref[6:8], [-0.52, -0.69], [0.17, 0.48])
            try:
                q_contact = self._solve(t_palm[:3, 3], t_palm[:3, :3], contact_ref)
            except ValueError as exc:
                self.notes.append(f"place sign {sign:+.0f}: {exc}")
                continue
            q_place = q_contact - sign * motion
            if self.motion == "finger_squeeze":
                q_place = q_contact.copy()
                q_place[_J["ARTz"]] += 0.03
            back = self._fv_back(q_place, tool_in_palm, fv_center_local, obj_p, obj_r @ self.spec.push)
            if best is None or back > best[0] + 1e-6:
                best = (back, q_place, q_contact, sign)
        if best is None:
            raise ValueError("no reachable place pose: " + "; ".join(self.notes))
        _, q_place, q_contact, sign = best
        q_strike = q_contact + sign * motion * MOTION_OVERSHOOT
        lower, upper = self._limits()
        q_strike = np.clip(q_strike, lower, upper)
        q_place = np.clip(q_place, lower, upper)
        q_hover = q_place.copy()
        q_hover[_J["ARTz"]] += self.cfg.hover_height
        return q_hover, q_place, q_strike

    def _fv_back(self, q: np.ndarray, tool_in_palm: np.ndarray, fv_center_local: np.ndarray,
                 obj_p: np.ndarray, push: np.ndarray) -> float:
        """How far T_fv's centre lies behind the object along the motion's direction ``push`` (world) at
        joint targets q (for the hammer: its height above the nail)."""
        m = self.root @ self.ik.link_pose(q)
        t_tool = m @ tool_in_palm
        c = t_tool[:3, :3] @ fv_center_local + t_tool[:3, 3]
        return float(np.dot(obj_p - c, push))

    def _limits(self) -> tuple[np.ndarray, np.ndarray]:
        lim = np.asarray(self.art.get_qlimit(), dtype=np.float64)[self.perm]
        return lim[:, 0], lim[:, 1]

    # ------------------------------------------------------------------ loop
    def run(self, on_stage_end: Callable[[str, int], None] | None = None) -> EpisodeResult:
        cfg = self.cfg
        frames = self.spec.stage_frames(cfg.n_frames)
        bounds = np.concatenate([[0], np.cumsum(frames)])
        starts = {int(bounds[i]): i for i in range(len(STAGES)) if frames[i] > 0}  # first frame -> stage
        n = int(cfg.n_frames)
        n_rec = (n + cfg.record_every - 1) // cfg.record_every
        rec = {
            "frame": np.zeros(n_rec, np.int64), "stage": np.zeros(n_rec, np.int64),
            "qpos": np.zeros((n_rec, N_JOINTS)), "qvel": np.zeros((n_rec, N_JOINTS)), "target": np.zeros((n_rec, N_JOINTS)),
            "force": np.zeros((n_rec, N_SENSORS)), "contact_pos": np.zeros((n_rec, N_SENSORS, 3)),
            "contact_normal": np.zeros((n_rec, N_SENSORS, 3)), "palm_pose": np.zeros((n_rec, 7)),
            "tool_pose": np.zeros((n_rec, 7)), "object_pose": np.zeros((n_rec, 7)),
        }
        lower, upper = self._limits()
        q_home = self._qpos()
        self.current_target = q_home.copy()
        self._write_targets(q_home)
        waypoints: dict[int, np.ndarray] = {}
        anchors_at_grasp = np.full((N_ANCHORS, 3), np.nan)
        gv_at_grasp = self.env.tool_gv_world()
        blowup = False
        reason = ""
        stage = -1
        grasp_stage = STAGES.index("grasp")
        plan_targets = np.empty((0, N_JOINTS))
        moving: np.ndarray = np.zeros(0, np.int64)
        stage_start = 0
        scene_step = self.env.step_physics
        record_every = cfg.record_every
        perf_counter = time.perf_counter
        physics_time = 0.0
        hook_time = 0.0  # time spent in on_stage_end, left out of wall_time_s
        k = 0
        t0 = time.perf_counter()
        for frame in range(n):
            if frame in starts:
                if on_stage_end is not None and stage >= 0:
                    th = perf_counter()
                    on_stage_end(STAGES[stage], frame - 1)
                    hook_time += perf_counter() - th
                if stage == grasp_stage:  # the grasp has just ended
                    anchors_at_grasp = self.ik.anchors_world(self._qpos(), root=self.root)
                    gv_at_grasp = self.env.tool_gv_world()
                stage = starts[frame]
                stage_start = frame
                plan_targets, moving = self._stage_trajectory(stage, frames[stage], waypoints, lower, upper)
            if moving.size:
                target = plan_targets[frame - stage_start]
                for i in moving:
                    self.joints[self.perm[i]].set_drive_target(float(target[i]))
                self.current_target = target
            ts = perf_counter()
            scene_step()
            physics_time += perf_counter() - ts
            if frame % record_every == 0:
                qpos, qvel = self._qpos(), self._qvel()
                force, cpos, cnormal = self.sensors.read()
                tool7 = _sapien_pose7(self.tool_body.get_entity_pose())
                lin = np.asarray(self.tool_body.get_linear_velocity(), dtype=np.float64)
                obj_p, obj_r = self.env.object_frame_world()
                # one sum: NaN or inf in any recorded array makes it non-finite (cheaper than 9 isfinite scans)
                if not math.isfinite(qpos.sum() + qvel.sum() + tool7.sum() + lin.sum() + force.sum() + cpos.sum()
                                     + cnormal.sum() + obj_p.sum() + obj_r.sum()):
                    blowup = True
                    reason = f"blowup: non-finite state at frame {frame} (not recorded)"
                    break
                if np.linalg.norm(lin) > cfg.blowup_speed:
                    blowup = True
                    reason = f"blowup: tool speed {np.linalg.norm(lin):.1f} m/s at frame {frame}"
                rec["frame"][k] = frame
                rec["stage"][k] = stage
                rec["qpos"][k] = qpos
                rec["qvel"][k] = qvel
                rec["target"][k] = self.current_target
                rec["force"][k] = force
                rec["contact_pos"][k] = cpos
                rec["contact_normal"][k] = cnormal
                rec["palm_pose"][k] = _sapien_pose7(self.palm_body.get_entity_pose())
                rec["tool_pose"][k] = tool7
                rec["object_pose"][k] = _pose7(obj_p, obj_r)
                k += 1
                if blowup:
                    break
        wall = time.perf_counter() - t0 - hook_time
        if on_stage_end is not None and stage >= 0:
            on_stage_end(STAGES[stage], frame)  # the last stepped frame (n - 1 unless it blew up)
        rec = {key: value[:k] for key, value in rec.items()}
        info = self.env.evaluate()
        outcome = {key: _to_python(value) for key, value in info.items()}
        outcome["blowup"] = blowup
        if blowup:
            outcome["success"] = False
            outcome["fail"] = True
            self.notes.append(reason)
            self.fault = "blowup"
        success = bool(outcome.get("success", False)) and not blowup
        n_stepped = frame + 1
        return EpisodeResult(
            plan=self.plan.copy(), outcome=outcome, success=success, anchors_at_grasp=anchors_at_grasp,
            gv_at_grasp=tuple(np.asarray(x).copy() for x in gv_at_grasp), stage_frames=frames,
            wall_time_s=wall, physics_time_s=physics_time, fps=(n if not blowup else n_stepped) / wall if wall > 0 else 0.0,
            notes=self.notes, fault=self.fault, **rec,
        )

    def _stage_trajectory(self, stage: int, n_frames: int, waypoints: dict[int, np.ndarray],
                          lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-frame targets (n_frames, 30) of a stage (min-jerk ramp from the current target to the
        stage's waypoint, planned now from the measured state) and the joints whose target moves."""
        start_q = self.current_target.copy()
        try:
            end_q = self._plan_stage(stage, waypoints, start_q)
            if not np.all(np.isfinite(end_q)):
                raise ValueError(f"non-finite joint target {np.round(end_q, 4).tolist()}")
        except PLANNING_ERRORS as exc:  # unreachable: hold still, the plan then fails physically
            self.notes.append(f"{STAGES[stage]}: {type(exc).__name__}: {exc}")
            self.fault = self.fault or "unreachable"
            end_q = start_q.copy()
        end_q = np.clip(end_q, lower, upper)
        waypoints[stage] = end_q
        if STAGES[stage] == "motion":
            settle = int(n_frames * self.cfg.strike_settle_frac)
            ramp = self.cfg.strike_ramp_frames if self.spec.motion_s is None else round(self.spec.motion_s * self.sim_freq)
            ramp_start, ramp_len = settle, max(1, min(ramp, n_frames - settle))
        elif STAGES[stage] == "grasp":  # per-joint closing windows of the posture
            a, b = GRASP_POSTURES[self.pattern].windows()
            ramp_start, ramp_len = a * n_frames, (b - a) * n_frames
        else:
            ramp_start, ramp_len = 0, n_frames
        s = (np.arange(n_frames)[:, None] + 1 - np.atleast_1d(ramp_start)) / np.atleast_1d(ramp_len)
        targets = start_q + (end_q - start_q) * _min_jerk(s)
        moving = np.nonzero(np.abs(end_q - start_q) > 1e-12)[0]
        return targets, moving

    def _plan_stage(self, stage: int, waypoints: dict[int, np.ndarray], start_q: np.ndarray) -> np.ndarray:
        name = STAGES[stage]
        if name == "pregrasp":
            far, self._ahead["approach"] = self.plan_pregrasp(start_q)
            return far
        if name == "grasp":
            return self.plan_grasp(start_q)
        if name == "lift":
            return self.plan_lift(start_q)
        if name == "transport":
            hover, self._ahead["place"], self._ahead["motion"] = self.plan_place(start_q)
            return hover
        if name in ("approach", "place") or (name == "motion" and self.spec.runs("place")):
            if name not in self._ahead:  # the stage that plans it could not: hold still, the plan fails
                raise ValueError(f"no {name} target: the stage that plans it found none")
            return self._ahead[name]
        if name == "motion":
            # no place stage: the motion acts from where the grasp left the hand, along the template's "+" sign
            return start_q + self._motion_vector() * (1.0 + MOTION_OVERSHOOT)
        q = start_q.copy()  # post_lift
        q[_J["ARTz"]] += self.spec.post_lift_height
        return q


def _to_python(value: Any) -> Any:
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    value = np.asarray(value)
    if value.size == 1:
        item = value.reshape(-1)[0].item()
        return item
    return value.tolist()


# ----------------------------------------------------------------------------- CLI
def _parse_plan(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",")]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"plan must be comma-separated integers, got {text!r}") from exc


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Execute PRL plans in simulation and report success rates.")
    parser.add_argument("--task", default="hammer")
    parser.add_argument("--plan", type=_parse_plan, default=[0, 3, 2, 0, 0, 1], help="e.g. 0,3,2,0,0,1")
    parser.add_argument("--scenes", type=int, default=20, help="randomised scenes for the given plan")
    parser.add_argument("--random-plans", type=int, default=0, help="also run this many uniformly random plans")
    parser.add_argument("--seed", type=int, default=0, help="first scene seed")
    parser.add_argument("--frames", type=int, default=None, help="physics frames per episode (default: 3 s)")
    parser.add_argument("--verbose", action="store_true")
    args = parser.parse_args(argv)

    import envs.agents  # noqa: F401  (registers prl_hand)
    from envs.tasks import make_env

    env = make_env(args.task)
    executor = PlanExecutor(env, ExecutorConfig(n_frames=args.frames))
    plan = executor.validate(args.plan)
    print(f"task {args.task}, plan {plan.tolist()}: {executor.plb.describe(plan)}")
    ok, fps, ratio = [], [], []
    for i in range(args.scenes):
        result = executor.run(plan, seed=args.seed + i)
        ok.append(result.success)
        fps.append(result.fps)
        if i > 0:  # the first episode pays one-off imports (pytorch-kinematics)
            ratio.append(result.physics_time_s / result.wall_time_s)
        if args.verbose:
            print(f"  seed {args.seed + i}: success={result.success} descent={result.outcome.get('nail_descent_cm')} "
                  f"fps={result.fps:.0f} notes={result.notes}")
    if args.scenes:
        print(f"plan {plan.tolist()}: success {np.sum(ok)}/{len(ok)} = {np.mean(ok):.2f}; "
              f"executor {np.mean(fps):.0f} frames/s")
    if args.random_plans:
        rng = np.random.default_rng(args.seed)
        rand_ok = []
        for i in range(args.random_plans):
            random_plan = np.array([rng.integers(0, s) for s in executor.plb.sizes])
            result = executor.run(random_plan, seed=10_000 + args.seed + i)
            rand_ok.append(result.success)
            if args.verbose:
                print(f"  random {random_plan.tolist()}: success={result.success} "
                      f"descent={result.outcome.get('nail_descent_cm')}")
        print(f"uniformly random plans: success {np.sum(rand_ok)}/{len(rand_ok)} = {np.mean(rand_ok):.2f}")
    if ratio:
        print(f"physics share of the executor loop (physics_time_s / wall_time_s): {np.mean(ratio):.2f}; "
              "for frames/s against raw scene.step() and env.step run `python -m bench.bench_executor`")
    env.close()


if __name__ == "__main__":
    main()
