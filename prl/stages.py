"""The plan executor's stages, the faults it may report and the grasp postures, as data.

No simulator dependency (so it lives in ``prl``): the tasks declare their ``StageSpec`` with it, the
executor (``envs.executor``) runs it, and label recovery reads recorded stage indices against the same
``STAGES`` tuple. The stages, in order:

0. ``pregrasp``  put the chosen palm anchor (a2) on the centre line of T_gv, a few cm out along the
   palm normal, the palm rotated relative to T_gv by Rx(a0) Rz(a1); fingers pre-shaped for the pattern.
1. ``approach``  move along the palm normal until the anchor is at the pattern's gap from the tool.
2. ``grasp``     close the fingers into the pattern's posture (a3, :data:`GRASP_POSTURES`).
3. ``lift``      lift the hand (and, if the grasp holds, the tool) straight up.
4. ``transport`` move above the object, aligning the object's Z axis with the chosen T_fv axis (a5).
5. ``place``     bring T_fv's leading face near the object, on the side the task declares.
6. ``motion``    the kinematic motion (a4) along its catalogue template.
7. ``post_lift`` lift the hand again after the motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from prl.constants import JOINT_NAMES, N_JOINTS

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

JOINT_INDEX: dict[str, int] = {name: i for i, name in enumerate(JOINT_NAMES)}
FINGER = slice(8, 30)


def _posture(**values: float) -> np.ndarray:
    """A (22,) finger posture from joint-name keyword values (others 0)."""
    q = np.zeros(N_JOINTS)
    for name, value in values.items():
        q[JOINT_INDEX[name]] = value
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
