"""What a plan execution is configured by (``ExecutorConfig``) and what it returns (``EpisodeResult``).

Plain data, no simulator dependency; ``envs.executor`` and ``envs.episode`` use it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from prl.constants import EPISODE_SECONDS, RECORD_HZ
from prl.demo import X_MANIP_DIM, X_MANIP_SAMPLES


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
    end_decided: bool = False
    """End a plan episode early, as a failure, once its task says that it can no longer succeed
    (``PRLTaskEnv.failure_decided``, asked at every stage boundary): the frames left are not stepped, and the
    result says so (``EpisodeResult.decided``, ``outcome["decided"]``; ``frames_stepped`` counts the frames run).
    A success always runs to its end. The measures in ``outcome`` are then those at the early end, not the full
    episode's: only for callers that keep nothing of a failed episode but that it failed (synthesis attempts),
    not where a failure's final measure or trajectory is read (the LN's reward). False (the default): every
    episode runs its ``n_frames``, exactly as without this option."""

    def __post_init__(self) -> None:
        if self.n_frames is not None and self.n_frames < 100:
            raise ValueError(f"n_frames must be >= 100, got {self.n_frames!r}")
        if self.observe_frames is not None and self.observe_frames < X_MANIP_SAMPLES:
            raise ValueError(f"observe_frames must be >= {X_MANIP_SAMPLES}, got {self.observe_frames!r}")
        if not isinstance(self.end_decided, bool):
            raise TypeError(f"end_decided must be True or False, got {self.end_decided!r}")
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
    frames_stepped: int = 0
    """Physics frames of the plan episode actually stepped: ``n_frames``, fewer after a blow-up or an early end."""
    decided: str = ""
    """Why the episode was ended early as a decided failure (``ExecutorConfig.end_decided``): the stage after
    which and the task's reason (as ``outcome["decided"]``); "" when it ran to its end."""
    notes: list[str] = field(default_factory=list)
    """Planner notes (e.g. an unreachable target replaced by the nearest reachable one)."""
    fault: str = ""
    """Why the executor, not physics alone, ended the plan: ``""`` (nothing went wrong in planning or
    simulation), or one of ``FAULTS``; the details are in ``notes``."""
    x_manip: np.ndarray = field(default_factory=lambda: np.zeros(X_MANIP_DIM, np.float32))
    """(784,) features of the observation phase before the plan acted (``prl.demo`` layout)."""
    scene_bodies: tuple[str, ...] = ()
    """Names of the other bodies that move (``envs.scene_record.SceneParts``: non-static actors, then the
    non-hand articulations' roots)."""
    scene_joints: tuple[str, ...] = ()
    """Names ``<articulation>/<joint>`` of the non-hand articulations' joints."""
    scene_pose: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 7)))
    """(T, bodies, 7) pose of each of ``scene_bodies`` at each record."""
    scene_qpos: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    """(T, joints) position of each of ``scene_joints`` at each record."""
