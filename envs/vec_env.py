"""SB3 vector environments of the LN: plan or joint-control environments of one task, one per rank (the caller
names the environment's class, so that this module decides no method's outcome but through the class it is given).

One env steps in this process; more step in parallel in spawned subprocesses (one scene each), each worker
frozen out of the garbage collector's walks for its whole life (``fast_resets``).
"""

from __future__ import annotations

import os
from functools import partial
from typing import Any

import gymnasium as gym
import torch

from envs.tasks import fast_resets


def make_vec_env(env_class: type[gym.Env], task: str, n_envs: int = 1, run_seed: int = 0, **kwargs: Any) -> Any:
    """An SB3 vector env of ``n_envs`` ``env_class`` environments (``envs.plan_env.PlanEnv`` or
    ``envs.joint_env.JointControlEnv``) of ``task``, ranks 0..n_envs-1 of the ``run_seed`` stream; ``kwargs`` go to
    the env. One env steps in this process; more step in parallel in spawned subprocesses, one scene each."""
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv  # heavy: only the LN needs SB3

    if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
        raise ValueError(f"n_envs must be an integer >= 1, got {n_envs!r}")
    fns = [partial(_make_env, env_class, task, run_seed, rank, n_envs > 1, kwargs) for rank in range(n_envs)]
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


def _make_env(env_class: type[gym.Env], task: str, run_seed: int, rank: int, own_process: bool,
              kwargs: dict[str, Any]) -> gym.Env:
    env = env_class(task, run_seed=run_seed, rank=rank, **kwargs)
    if hasattr(env, "warm_up"):
        env.warm_up()  # everything a first episode creates exists before any fast_resets() freeze
    elif hasattr(env, "build"):
        env.build()
    if own_process:  # a worker process that only steps this env
        torch.set_num_threads(1)  # one core per env: PointNet and the text encoder must not fight the other env
        global _WORKER_FREEZE  # held for the worker's life: a dropped context manager's generator
        # is collected at once and its ``finally`` unfreezes (the workers ran unfrozen at 0.7 s per plan, not 0.35)
        _WORKER_FREEZE = fast_resets()
        _WORKER_FREEZE.__enter__()  # the imports and the simulator stay out of every reset's gc.collect()
    return env


_WORKER_FREEZE: Any = None
"""The ``fast_resets`` block a vector-env worker stays in (see ``_make_env``)."""
