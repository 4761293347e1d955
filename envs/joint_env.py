"""The joint-control baseline's environment (paper Fig 8 top): A2C acting on the hand's 30 joint targets.

``JointControlEnv(task)`` runs the same task scenes as ``envs.plan_env.PlanEnv`` (the same scene-seed
stream for equal ``run_seed`` and ``rank``), with ManiSkill's ``pd_joint_pos`` controller of the PRL
hand. An action in [-1, 1]^30 maps linearly onto the joints' limits (the floating base's translation
limits are +-1 m around the rest pose, its rotations +-pi); each step holds that target for
``frames_per_step`` physics frames (10), and an episode is ``steps`` steps (150, i.e. 1500 frames). The
observation is ManiSkill's flat ``state`` (the hand's qpos and qvel, the task's tool and object state)
plus the elapsed fraction of the episode. The reward of a step is the change of the task's measure
over it, so an episode's return is the task's measure at its end (the plan env's reward); success and
the measure at the end are in the last step's ``info``, where ``frames`` is the episode's physics frames.
The episode ends with ``terminated=True`` at its fixed horizon (the task's end, not a time limit).
"""

from __future__ import annotations

import logging
import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from tqdm.auto import tqdm

from envs.scene_stream import SceneStream
from envs.tasks import make_env, task_class
from envs.trials import TrialOutcome, error_text

_log = logging.getLogger(__name__)

JOINT_FRAMES_PER_STEP = 10
"""Physics frames per joint-control step."""
JOINT_STEPS = 150
"""Steps per joint-control episode (150 x 10 = 1500 frames)."""


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
        self._build()
        obs_dim = int(np.prod(self._env.observation_space.shape[1:])) + 1
        self.action_space = gym.spaces.Box(-1.0, 1.0, (self._low.size,), np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32)
        self._t = 0
        self._measure = 0.0

    def _build(self) -> None:
        self._env = make_env(self.task, control_mode="pd_joint_pos", obs_mode="state",
                             randomization=self.randomization)
        u = self._env.unwrapped
        per_control = int(u.sim_freq // u.control_freq)
        if self.frames_per_step % per_control:
            raise ValueError(f"frames_per_step={self.frames_per_step} is not a multiple of the {per_control} physics "
                             f"frames of one control step ({u.sim_freq} Hz / {u.control_freq} Hz)")
        self._repeat = self.frames_per_step // per_control
        limits = u.agent.robot.get_qlimits()[0].cpu().numpy().astype(np.float64)
        self._low, self._high = limits[:, 0], limits[:, 1]

    def _obs(self, obs: Any) -> np.ndarray:
        flat = np.asarray(obs.cpu().numpy() if hasattr(obs, "cpu") else obs, np.float32).reshape(-1)
        return np.nan_to_num(np.append(flat, self._t / self.steps).astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.next_scene(seed, options)
        if self._env is None:
            self._build()
        obs, _ = self._env.reset(seed=self.scene_seed)
        self._t, self._measure = 0, 0.0
        return self._obs(obs), {"scene_seed": self.scene_seed}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        a = np.asarray(action, np.float64).reshape(-1)
        if a.shape != self._low.shape:
            raise ValueError(f"a joint action has {self._low.size} values, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"joint action holds non-finite values: {a.tolist()}")
        target = self._low + (np.clip(a, -1.0, 1.0) + 1.0) / 2.0 * (self._high - self._low)
        info: dict[str, Any] = {"scene_seed": self.scene_seed, "error": "", "fault": ""}
        try:
            command = torch.as_tensor(target, dtype=torch.float32)[None]
            with warnings.catch_warnings():  # ManiSkill's NaN check calls np.isnan on the tensor (NumPy 2 deprecation)
                warnings.simplefilter("ignore", DeprecationWarning)
                for _ in range(self._repeat):
                    obs, _, _, _, sim_info = self._env.step(command)
            measure = float(sim_info[self.measure_key].reshape(-1)[0])
            success = bool(sim_info["success"].reshape(-1)[0])
        except Exception as exc:  # noqa: BLE001 - one episode's error must not end training
            info["error"] = error_text(exc)
            _log.warning("%s joint episode on scene %d raised: %s", self.task, self.scene_seed, info["error"])
            self.close()
            info.update(success=False, measure=0.0, frames=(self._t + 1) * self.frames_per_step)
            return np.zeros(self.observation_space.shape, np.float32), -self._measure, True, False, info
        self._t += 1
        measure = measure if np.isfinite(measure) else 0.0
        reward, self._measure = measure - self._measure, measure
        done = self._t >= self.steps
        if done:
            info.update(success=success, measure=measure, frames=self._t * self.frames_per_step)
        return self._obs(obs), float(reward), done, False, info

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
