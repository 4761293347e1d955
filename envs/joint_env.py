"""The joint-space methods' environment (paper Fig 8 top): the hand's 30 joint targets at the dataset's rate.

``JointControlEnv(task)`` runs the same task scenes as ``envs.plan_env.PlanEnv`` (the same scene-seed stream for
equal ``run_seed`` and ``rank``) with the PRL hand's joint drives (the stiffness and damping of its ``pd_joint_pos``
controller). An action in [-1, 1]^30 maps linearly onto each joint's own limits, looked up by name: the
controller's action space holds them in ``JOINT_NAMES`` order (the floating base's translation limits are +-1 m
around the rest pose, its rotations +-pi); ``target_of`` gives the joint targets of an action, and ``step_target``
steps with joint targets directly (a policy trained on a dataset's ``action``, or a replay). A step lasts
``frames_per_step`` physics frames (5: the dataset's 50 Hz) and an episode ``steps`` steps (150: the plan episode's
750 frames). Over a step the drive targets move linearly, frame by frame, from the last step's target to the new
one, which they reach at the step's last frame, as a robot's joint controller interpolates the commands of a slower
policy (the plan executor also moves its targets every frame; ``prl.export_schema.replay_actions``). The reset runs
the plan executor's observation phase (the hand held at home while the scene settles) and the plan's first frame,
so the first observation is a demonstration's first recorded frame and the observation after step k its record
k + 1.

The observation is the export's (``prl.export_schema``): ``observation.state`` (qpos | qvel in ``JOINT_NAMES``
order), ``observation.environment_state`` (``prl.env_state``), then the elapsed fraction of the episode
(``observation_parts`` splits it). The reward of a step is the change of the task's measure over it, so an episode's
return is the task's measure at its end (the plan env's reward); success and the measure at the end are in the last
step's ``info``, where ``frames`` is the episode's physics frames. A measure that the plan executor counts from a
stage (the unscrew's turn, from the motion) counts from the reset here: joint control has no stages. The episode
ends with ``terminated=True`` at its fixed horizon (the task's end, not a time limit).
"""

from __future__ import annotations

import logging
from typing import Any

import gymnasium as gym
import numpy as np
from tqdm.auto import tqdm

from envs.episode import pose7
from envs.execution import ExecutorConfig
from envs.scene_record import SceneParts, sapien_pose7
from envs.scene_stream import SceneStream
from envs.tasks import make_env, task_class
from envs.trials import TrialOutcome, error_text
from prl.constants import EPISODE_FRAMES, JOINT_NAMES, N_JOINTS, RECORD_HZ, SIM_FREQ
from prl.env_state import ENV_STATE_DIM, environment_state

_log = logging.getLogger(__name__)

JOINT_FRAMES_PER_STEP = SIM_FREQ // RECORD_HZ
"""Physics frames per joint-control step: one step at the dataset's rate (5 at 250 Hz and 50 fps)."""
JOINT_STEPS = EPISODE_FRAMES // JOINT_FRAMES_PER_STEP
"""Steps per joint-control episode: the plan episode's 750 frames (150 steps)."""
STATE_DIM = 2 * N_JOINTS
"""Values of ``observation.state`` at the head of an observation (qpos | qvel)."""


def observation_parts(obs: np.ndarray) -> dict[str, np.ndarray]:
    """A joint-control observation (or a batch of them) split into the export's features and the elapsed fraction:
    ``observation.state``, ``observation.environment_state`` and ``elapsed``."""
    obs = np.asarray(obs)
    return {"observation.state": obs[..., :STATE_DIM],
            "observation.environment_state": obs[..., STATE_DIM:STATE_DIM + ENV_STATE_DIM],
            "elapsed": obs[..., STATE_DIM + ENV_STATE_DIM:]}


class JointControlEnv(SceneStream, gym.Env):
    """30-D joint position targets on ``task``'s randomised scenes; see the module docstring."""

    metadata = {"render_modes": []}  # noqa: RUF012 (gymnasium class attribute)

    def __init__(self, task: str, run_seed: int = 0, rank: int = 0, randomization: float = 1.0,
                 frames_per_step: int = JOINT_FRAMES_PER_STEP, steps: int = JOINT_STEPS) -> None:

        self.measure_key = task_class(task).measure_key  # ValueError naming an unknown task
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ValueError(f"steps must be an integer >= 1, got {steps!r}")
        if isinstance(frames_per_step, bool) or not isinstance(frames_per_step, int) or frames_per_step < 1:
            raise ValueError(f"frames_per_step must be an integer >= 1, got {frames_per_step!r}")
        self.task, self.run_seed, self.rank = task, int(run_seed), int(rank)
        self.randomization, self.frames_per_step, self.steps = float(randomization), frames_per_step, steps
        self.episode = 0
        self.scene_seed: int | None = None
        self._env: Any = None
        self._parts: SceneParts | None = None
        self._build()
        self.action_space = gym.spaces.Box(-1.0, 1.0, (N_JOINTS,), np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (STATE_DIM + ENV_STATE_DIM + 1,), np.float32)
        self._t = 0
        self._measure = 0.0

    def _build(self) -> None:
        self._env = make_env(self.task, control_mode="pd_joint_pos", randomization=self.randomization)
        u = self._env.unwrapped
        controller = u.agent.controller
        names = tuple(j.name for j in controller.joints)
        if names != JOINT_NAMES:
            raise RuntimeError(f"the pd_joint_pos controller drives {names}, not JOINT_NAMES")
        space = controller.single_action_space  # the controlled joints' own limits, in JOINT_NAMES order
        self._low = np.asarray(space.low, np.float64).reshape(-1)
        self._high = np.asarray(space.high, np.float64).reshape(-1)

    def target_of(self, action: Any) -> np.ndarray:
        """The joint targets (30, ``JOINT_NAMES`` order) of an action in [-1, 1]^30 (clipped): -1 is each joint's
        lower limit, +1 its upper. ValueError naming a wrong shape or a non-finite value."""
        a = np.asarray(action, np.float64).reshape(-1)
        if a.shape != (N_JOINTS,):
            raise ValueError(f"a joint action has {N_JOINTS} values, got shape {np.shape(action)}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"joint action holds non-finite values: {a.tolist()}")
        return self._low + (np.clip(a, -1.0, 1.0) + 1.0) / 2.0 * (self._high - self._low)

    def _obs(self) -> np.ndarray:
        u = self._env.unwrapped
        tool = sapien_pose7(u.tool._bodies[0].get_entity_pose())
        obj = pose7(*u.object_frame_world())
        env_state = environment_state(tool, obj, self._parts.poses(), self._parts.qpos())
        out = np.concatenate([u.agent.named_qpos(), u.agent.named_qvel(), env_state, [self._t / self.steps]])
        return np.nan_to_num(out.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.next_scene(seed, options)
        if self._env is None:
            self._build()
        self._env.unwrapped.reset(seed=self.scene_seed)
        u = self._env.unwrapped
        self._joints = [u.agent.robot._objs[0].get_active_joints()[i] for i in u.agent.joint_perm]
        # as the plan executor: hold the pose through the observation phase, then the measured pose through the plan's
        # first frame, every drive written each time
        for frames in (ExecutorConfig().at_rate(u.sim_freq).observe_frames, 1):
            self._written = np.full(N_JOINTS, np.nan)
            self._target = u.agent.named_qpos()
            self._write(self._target)
            for _ in range(frames):
                u.step_physics()
        self._parts = SceneParts(self._env)
        self._t, self._measure = 0, 0.0
        return self._obs(), {"scene_seed": self.scene_seed}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        return self.step_target(self.target_of(action))

    def step_target(self, target: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """One step towards the joint ``target`` (30, ``JOINT_NAMES`` order, clipped to the joints' limits), reached
        at the step's last frame, as ``step`` does with the targets of its action."""
        target = np.clip(np.asarray(target, np.float64).reshape(-1), self._low, self._high)
        if target.shape != (N_JOINTS,) or not np.all(np.isfinite(target)):
            raise ValueError(f"a joint target has {N_JOINTS} finite values, got {np.round(target, 4).tolist()}")
        info: dict[str, Any] = {"scene_seed": self.scene_seed, "error": "", "fault": ""}
        try:
            u, start = self._env.unwrapped, self._target
            for j in range(1, self.frames_per_step + 1):
                self._write(start + (target - start) * (j / self.frames_per_step))
                u.step_physics()
            self._target = target
            sim_info = u.evaluate()
            measure = float(sim_info[self.measure_key].reshape(-1)[0])
            success = bool(sim_info["success"].reshape(-1)[0])
            self._t += 1
            obs = self._obs()
        except Exception as exc:  # noqa: BLE001 - one episode's error must not end training
            info["error"] = error_text(exc)
            _log.warning("%s joint episode on scene %d raised: %s", self.task, self.scene_seed, info["error"])
            self.close()
            info.update(success=False, measure=0.0, frames=(self._t + 1) * self.frames_per_step)
            return np.zeros(self.observation_space.shape, np.float32), -self._measure, True, False, info
        measure = measure if np.isfinite(measure) else 0.0
        reward, self._measure = measure - self._measure, measure
        done = self._t >= self.steps
        if done:
            info.update(success=success, measure=measure, frames=self._t * self.frames_per_step)
        return obs, float(reward), done, False, info

    def _write(self, target: np.ndarray) -> None:
        """Set the drive targets that differ from the ones written last (as the plan executor writes only the
        joints whose target moves: a drive target written wakes the hand in PhysX, so writing unchanged ones
        would keep awake a hand that the executor lets sleep)."""
        for i in np.flatnonzero(target != self._written):
            self._joints[i].set_drive_target(float(target[i]))
        self._written = np.array(target, dtype=np.float64)

    def on_stage_start(self, stage: str) -> None:
        """Tell the task that a plan stage starts (``prl.stages`` names), as the plan executor does: a replay of a
        demonstration (``envs.replay``) calls it where the recorded stage changes, so a measure that counts from a
        stage counts as it did when the demonstration was recorded."""
        self._env.unwrapped.on_stage_start(stage)

    def close(self) -> None:
        if self._env is not None:
            self._env.close()
        self._env = None


def run_joint_policy(task: str, policy: Any, seeds: list[int], randomization: float = 1.0,
                     progress: bool = True) -> list[Any]:
    """The deterministic joint-control ``policy`` (an SB3 policy) for one episode on the scene of each seed;
    one ``envs.trials.TrialOutcome`` each (plan ``()``: there is none)."""
    env = JointControlEnv(task, randomization=randomization)
    out = []
    try:
        for seed in tqdm(seeds, desc=f"{task} joint-control episodes", disable=not progress, unit="episode"):
            obs, _ = env.reset(options={"scene_seed": int(seed)})
            done, info = False, {}
            while not done:
                action, _ = policy.predict(obs[None], deterministic=True)
                obs, _, done, _, info = env.step(action[0])
            out.append(TrialOutcome(task=task, seed=int(seed), plan=(), success=bool(info["success"]),
                                    measure=float(info["measure"]), fail=bool(info["error"]), error=info["error"]))
    finally:
        env.close()
    return out


def run_target_policy(task: str, actor: Any, seeds: list[int], randomization: float = 1.0,
                      progress: bool = True) -> list[Any]:
    """A policy that acts in joint targets (``actor(state, environment_state)`` -> 30 targets, ``actor.reset()`` at
    each episode's start: ``prl.imitation.ImitationActor``) for one episode on the scene of each seed, closed loop
    at the dataset's rate; one ``envs.trials.TrialOutcome`` each (plan ``()``), success by the task's own rule."""
    env = JointControlEnv(task, randomization=randomization)
    out = []
    try:
        for seed in tqdm(seeds, desc=f"{task} joint-space rollouts", disable=not progress, unit="episode"):
            obs, _ = env.reset(options={"scene_seed": int(seed)})
            actor.reset()
            done, info = False, {}
            while not done:
                parts = observation_parts(obs)
                target = actor(parts["observation.state"], parts["observation.environment_state"])
                obs, _, done, _, info = env.step_target(target)
            out.append(TrialOutcome(task=task, seed=int(seed), plan=(), success=bool(info["success"]),
                                    measure=float(info["measure"]), fail=bool(info["error"]), error=info["error"]))
    finally:
        env.close()
    return out
