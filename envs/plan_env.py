"""The Learning Network's environment: one step executes one whole plan (paper Sec. IV-B).

``PlanEnv(task, pointnet_path)`` is a gymnasium environment over a PRL task:

- ``reset()`` builds the randomised scene of the next episode seed, runs the observation phase
  (``PlanExecutor.observe``) and returns x, the RN's input ``[x_manip | TE | PN(tool) | PN(object)]``
  (``prl.features.scene_features``, the one definition shared with the RN);
- ``action_space`` is the Representation Space, ``MultiDiscrete(plb.sizes)``;
- ``step(plan)`` executes the plan from the observed state and returns the task's measured quantity
  as the reward (hammer nail descent d in cm, sweep cubes in the zone N, unscrew cap turn in degrees;
  paper Sec. V-A) with ``terminated=True``; ``info`` holds ``success``, ``measure``, ``fault``,
  ``error``, ``scene_seed``, ``plan`` and ``frames`` (physics frames stepped for this episode).

The reward is read from the simulated state by the task's ``evaluate()``; nothing else.

Scene seeds come from ``envs.scene_stream.SceneStream`` (shared with the joint-control baseline);
``envs.vec_env.make_vec_env`` steps several of these environments in parallel.
An attempt that raises (a PhysX error, a bug) is a failed episode with reward 0 and the error text in
``info["error"]``; the simulator is rebuilt at the next reset, so training goes on.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from envs.execution import ExecutorConfig
from envs.executor import PlanExecutor
from envs.scene_stream import SceneStream, ln_scene_seed
from envs.tasks import make_env, task_class
from envs.trials import error_text
from prl.constants import EPISODE_FRAMES
from prl.features import FEATURE_LAYOUT, scene_features
from prl.plb import load_plb
from prl.pointnet import load_pointnet

_log = logging.getLogger(__name__)


class PlanEnv(SceneStream, gym.Env):
    """One plan per episode on ``task``'s randomised scenes; see the module docstring."""

    metadata = {"render_modes": []}  # noqa: RUF012 (gymnasium class attribute)

    def __init__(self, task: str, pointnet_path: str | Path, n_points: int = 512, run_seed: int = 0, rank: int = 0,
                 randomization: float = 1.0, n_frames: int = EPISODE_FRAMES) -> None:
        cls = task_class(task)  # ValueError naming an unknown task
        if not randomization > 0:
            raise ValueError(f"randomization must be > 0, got {randomization!r}")
        self.task = task
        self.measure_key = cls.measure_key
        self.plb = load_plb()
        self.texts = self.plb.texts(task)
        self.pointnet = load_pointnet(pointnet_path)  # FileNotFoundError naming a missing checkpoint
        self.n_points = int(n_points)
        self.run_seed, self.rank = int(run_seed), int(rank)
        self.randomization, self.n_frames = float(randomization), int(n_frames)
        self.action_space = gym.spaces.MultiDiscrete(list(self.plb.sizes))
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (FEATURE_LAYOUT.dim,), np.float32)
        self.episode = 0
        """Index of the next training episode of the stream."""
        self.scene_seed: int | None = None
        """Seed of the scene the current episode runs on."""
        self._env: Any = None
        self._executor: Any = None
        self._x: np.ndarray | None = None
        self._ready = False

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.next_scene(seed, options)
        self._x = self._observe(self.scene_seed)
        self._ready = True
        return self._x.copy(), {"scene_seed": self.scene_seed}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._ready:
            raise RuntimeError("PlanEnv.step() before reset(): every episode is one plan on a freshly observed scene")
        plan = self.plb.validate_plan(action)  # ValueError naming a bad plan vector
        self._ready = False
        info: dict[str, Any] = {"scene_seed": self.scene_seed, "plan": plan.tolist(), "error": "", "fault": ""}
        try:
            result = self._executor.run(plan)
        except Exception as exc:  # noqa: BLE001 - one attempt's error must not end training
            info.update(success=False, measure=0.0, error=error_text(exc), frames=0)
            _log.warning("%s plan %s on scene %d raised: %s", self.task, plan.tolist(), self.scene_seed, info["error"])
            self.close()
            return self._x.copy(), 0.0, True, False, info
        measure = float(result.outcome[self.measure_key])
        measure = measure if np.isfinite(measure) else 0.0
        frames = int(self._executor.config.observe_frames + np.sum(result.stage_frames))
        info.update(success=bool(result.success), measure=measure, fault=result.fault, frames=frames)
        return self._x.copy(), measure, True, False, info

    def close(self) -> None:
        if self._env is not None:
            self._env.close()
        self._env = self._executor = None

    def build(self) -> None:
        """Create the simulator (done lazily by the first reset; again after an attempt raised)."""
        if self._env is None:
            self._env = make_env(self.task, randomization=self.randomization)
            self._executor = PlanExecutor(self._env, ExecutorConfig(n_frames=self.n_frames))

    def warm_up(self) -> None:
        """Build the simulator and load what a first episode loads (the text encoder, the IK chain) by running the
        task's expert plan once on the stream's first scene, without advancing the stream.

        Done before ``fast_resets`` freezes the heap, so that these objects are frozen too; made after the freeze,
        they would be walked by ManiSkill's ``gc.collect()`` on every scene rebuild."""
        self.build()
        stream = (self.episode, self.scene_seed)
        self.reset(options={"scene_seed": ln_scene_seed(self.run_seed, self.rank, 0)})
        self.step(task_class(self.task).expert_plan)
        self.episode, self.scene_seed = stream

    # ------------------------------------------------------------------ internals
    def _observe(self, scene_seed: int, tries: int = 3) -> np.ndarray:
        """x of the scene ``scene_seed`` after its observation phase (rebuilding the simulator after an error)."""
        for attempt in range(tries):
            self.build()
            try:
                x_manip = self._executor.observe(seed=scene_seed)
                params = dict(self._env.unwrapped.scene_params)
                break
            except Exception as exc:
                _log.warning("%s scene %d: observation raised (%s), rebuilding the simulator", self.task,
                             scene_seed, exc)
                self.close()
                if attempt == tries - 1:
                    raise
        text = self.texts[scene_seed % len(self.texts)]  # the same scene always reads the same sentence
        x = scene_features(self.task, scene_seed, params, x_manip, text, self.pointnet, self.n_points)[0]
        return np.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32)
