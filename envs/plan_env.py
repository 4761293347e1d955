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

Scene seeds: episode ``i`` of the stream ``(run_seed, rank)`` runs on ``ln_scene_seed(run_seed, rank, i)``;
``reset(seed=s)`` restarts the stream at episode 0 with run seed ``s``, and ``reset(options={"scene_seed": n})``
runs one episode on scene ``n`` without advancing the stream (evaluation).
An attempt that raises (a PhysX error, a bug) is a failed episode with reward 0 and the error text in
``info["error"]``; the simulator is rebuilt at the next reset, so training goes on.
"""

from __future__ import annotations

import logging
import os
import zlib
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from prl.constants import EPISODE_FRAMES

_log = logging.getLogger(__name__)


def ln_scene_seed(run_seed: int, rank: int, episode: int) -> int:
    """Scene seed of LN training episode ``episode`` of environment ``rank`` in a run seeded ``run_seed``.

    A hash, so it does not meet the RN evaluation's consecutive seeds (10,000,000 + ...) on which the
    final policy is evaluated, nor the trials' seeds, except by a 1-in-4-billion chance per pair."""
    return zlib.crc32(f"ln/{int(run_seed)}/{int(rank)}/{int(episode)}".encode())


class SceneStream:
    """The scene-seed stream of the LN's environments: ``run_seed``, ``rank``, the next ``episode`` and the
    current ``scene_seed`` (see the module docstring)."""

    run_seed: int
    rank: int
    episode: int = 0
    scene_seed: int | None = None

    def next_scene(self, seed: int | None, options: dict[str, Any] | None) -> int:
        """The scene of the episode a ``reset(seed=..., options=...)`` starts (and the stream advanced past it)."""
        if seed is not None:
            self.run_seed, self.episode = int(seed), 0
        if options and "scene_seed" in options:
            self.scene_seed = int(options["scene_seed"])
        else:
            self.scene_seed = ln_scene_seed(self.run_seed, self.rank, self.episode)
            self.episode += 1
        return self.scene_seed


class PlanEnv(SceneStream, gym.Env):
    """One plan per episode on ``task``'s randomised scenes; see the module docstring."""

    metadata = {"render_modes": []}  # noqa: RUF012 (gymnasium class attribute)

    def __init__(self, task: str, pointnet_path: str | Path, n_points: int = 512, run_seed: int = 0, rank: int = 0,
                 randomization: float = 1.0, n_frames: int = EPISODE_FRAMES) -> None:
        import envs  # noqa: F401  (registers the hand and the tasks, also in a vector-env subprocess)
        from envs.tasks import task_class
        from prl.features import FEATURE_LAYOUT
        from prl.plb import load_plb
        from prl.pointnet import load_pointnet

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
            from envs.trials import error_text

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
        from envs.executor import ExecutorConfig, PlanExecutor
        from envs.tasks import make_env

        if self._env is None:
            self._env = make_env(self.task, randomization=self.randomization)
            self._executor = PlanExecutor(self._env, ExecutorConfig(n_frames=self.n_frames))

    def warm_up(self) -> None:
        """Build the simulator and load what a first episode loads (the text encoder, the IK chain) by running the
        task's expert plan once on the stream's first scene, without advancing the stream.

        Done before ``fast_resets`` freezes the heap, so that these objects are frozen too; made after the freeze,
        they would be walked by ManiSkill's ``gc.collect()`` on every scene rebuild."""
        from envs.tasks import task_class

        self.build()
        stream = (self.episode, self.scene_seed)
        self.reset(options={"scene_seed": ln_scene_seed(self.run_seed, self.rank, 0)})
        self.step(task_class(self.task).expert_plan)
        self.episode, self.scene_seed = stream

    # ------------------------------------------------------------------ internals
    def _observe(self, scene_seed: int, tries: int = 3) -> np.ndarray:
        """x of the scene ``scene_seed`` after its observation phase (rebuilding the simulator after an error)."""
        from prl.features import scene_features

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


def make_vec_env(task: str, n_envs: int = 1, joint: bool = False, run_seed: int = 0, **kwargs: Any) -> Any:
    """An SB3 vector env of ``n_envs`` ``PlanEnv`` (or ``JointControlEnv`` when ``joint``) of ``task``, ranks
    0..n_envs-1 of the ``run_seed`` stream; ``kwargs`` go to the env. One env steps in this process; more
    step in parallel in spawned subprocesses, one scene each."""
    from functools import partial

    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
        raise ValueError(f"n_envs must be an integer >= 1, got {n_envs!r}")
    fns = [partial(_make_env, joint, task, run_seed, rank, n_envs > 1, kwargs) for rank in range(n_envs)]
    if n_envs == 1:
        return DummyVecEnv(fns)
    # one core per env: BLAS/OpenMP pools sized for the whole machine in every worker oversubscribe the cores
    single = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    saved = {name: os.environ.get(name) for name in single}
    os.environ.update(single)
    try:
        return SubprocVecEnv(fns, start_method="spawn")  # the workers start here and inherit the environment
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def _make_env(joint: bool, task: str, run_seed: int, rank: int, own_process: bool, kwargs: dict[str, Any]) -> gym.Env:
    if joint:
        from envs.joint_env import JointControlEnv

        env: gym.Env = JointControlEnv(task, run_seed=run_seed, rank=rank, **kwargs)
    else:
        env = PlanEnv(task, run_seed=run_seed, rank=rank, **kwargs)
    if hasattr(env, "warm_up"):
        env.warm_up()  # everything a first episode creates exists before any fast_resets() freeze
    elif hasattr(env, "build"):
        env.build()
    if own_process:  # a worker process that only steps this env
        import torch

        from envs.tasks import fast_resets

        torch.set_num_threads(1)  # one core per env: PointNet and the text encoder must not fight the other env
        global _WORKER_FREEZE  # held for the worker's life: a dropped context manager's generator
        # is collected at once and its ``finally`` unfreezes (the workers ran unfrozen at 0.7 s per plan, not 0.35)
        _WORKER_FREEZE = fast_resets()
        _WORKER_FREEZE.__enter__()  # the imports and the simulator stay out of every reset's gc.collect()
    return env


_WORKER_FREEZE: Any = None
"""The ``fast_resets`` block a vector-env worker stays in (see ``_make_env``)."""
