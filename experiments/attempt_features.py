"""The RN's input x of every synthesis attempt, failures included (the training set of the success critic,
``experiments.success_critic_model``).

A demo's x is stored with it; a failed attempt keeps only its scene seed and plan (``attempts.jsonl``). The
observation phase does not depend on the plan (``PlanExecutor.observe``), so resetting the scene of the attempt's
seed and observing gives the x the attempt's plan was chosen on: ``prl.features.scene_features``' layout, the
task sentence cycling through the task's phrasings as in the RN's evaluation. Only reset and observation run,
no plan: about a tenth of an attempt's physics.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from envs.execution import ExecutorConfig
from envs.executor import PlanExecutor
from envs.tasks import fast_resets, make_env
from prl.features import assemble, point_features
from prl.plb import load_plb


def observed_scenes(task: str, seeds: Sequence[int], progress: bool = True) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """Per seed, the observation phase's x_manip (N, 784) and the scene's ``scene_params``, in order."""
    x_manip, params = [], []
    with fast_resets():
        env = make_env(task)
        try:
            executor = PlanExecutor(env, ExecutorConfig())
            for seed in tqdm(list(seeds), desc=f"{task} scenes observed", unit="scene", disable=not progress):
                x_manip.append(executor.observe(seed=int(seed)))
                params.append(dict(env.unwrapped.scene_params))
        finally:
            env.close()
    return np.asarray(x_manip, dtype=np.float32), params


def attempt_features(task: str, seeds: Sequence[int], pointnet: Any, n_points: int,
                     progress: bool = True) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """x (N, 1680) of the scenes of ``seeds`` (the sentence of row i: the task's phrasing i modulo their number)
    and their ``scene_params``."""
    if not len(seeds):
        raise ValueError("no attempts: seeds is empty")
    x_manip, params = observed_scenes(task, seeds, progress)
    texts = load_plb().texts(task)
    tool, obj = point_features(pointnet, [task] * len(seeds), [int(s) for s in seeds], params, n_points)
    return assemble(x_manip, [texts[i % len(texts)] for i in range(len(seeds))], tool, obj), params
