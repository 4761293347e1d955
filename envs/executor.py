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
simulated state. NaN / blow-ups end the episode as a failure. With ``ExecutorConfig.end_decided`` an
episode also ends, as a failure, at the first stage boundary where its task says that it can no longer
succeed (``PRLTaskEnv.failure_decided``; ``EpisodeResult.decided`` says why).

The stage data are in ``prl.stages``, the config and result types in ``envs.execution``, the stepping
loop in ``envs.episode``. Success rates of a task's plans: ``python -m envs.trials --task hammer``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from envs.episode import Episode, pose7
from envs.execution import EpisodeResult, ExecutorConfig
from envs.scene_record import sapien_pose7
from envs.sensors import ContactSensors
from prl import plb as plb_module
from prl.demo import X_MANIP_LAYOUT, X_MANIP_SAMPLES, x_manip_from_samples


class PlanExecutor:
    """Executes plan vectors on a PRL task environment (``env.unwrapped`` of ``make_env``)."""

    def __init__(self, env: Any, config: ExecutorConfig | None = None) -> None:
        self.env = env.unwrapped if hasattr(env, "unwrapped") else env
        self.sim_freq = float(self.env.sim_freq)
        """Physics steps per second of the task's scene."""
        self.config = (config or ExecutorConfig()).at_rate(self.sim_freq)
        """The config with its frame counts fixed for ``sim_freq``."""
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
        that were never reached; after an early end (``ExecutorConfig.end_decided``), for each stage that ran and
        for none after. It is invoked only at stage boundaries, never per frame; None
        (the default) costs nothing. Time spent in the hook is not counted in ``wall_time_s``/``fps``.
        """
        plan = self.validate(plan)
        if seed is not None:
            self.env.reset(seed=int(seed))
            self._observation = None
        observation = self._observation if self._observation is not None else self.observe()
        self._observation = None
        result = Episode(self, plan).run(on_stage_end)
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
            samples["palm_pose"].append(sapien_pose7(palm.get_entity_pose()))
            samples["tool_pose"].append(sapien_pose7(tool.get_entity_pose()))
            samples["object_pose"].append(pose7(*env.object_frame_world()))
    return x_manip_from_samples({name: np.stack(v) for name, v in samples.items()})
