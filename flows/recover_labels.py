"""Stage ``labels``: the physical-law labels of each demo recovered from its recording (Eqs 4-9), with their
agreement with the commanded plans (child run ``labels``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from prefect import task
from prefect.cache_policies import INPUTS, NO_CACHE, TASK_SOURCE

from envs.tasks import task_class
from flows.artifacts import publish_table
from flows.synthesize import Synthesis
from prl import tracking
from prl.demo import load_demo
from prl.label_recovery import acted_mean, agreement, format_agreement, recover_plan
from prl.plb import load_plb


@dataclass(frozen=True)
class Labels:
    """Per task, the commanded and recovered plan vectors of its demos, in ``Synthesis.demo_paths`` order."""

    by_task: dict[str, dict[str, list[list[int]]]]

    def recovered_by_path(self, synthesis: Synthesis) -> dict[str, list[int]]:
        """Each demo file's recovered plan, keyed by its path as a string."""
        return {str(p): lab for name, paths in synthesis.demo_paths.items()
                for p, lab in zip(paths, self.by_task[name]["recovered"], strict=True)}


@task(name="recover-labels", task_run_name="labels-{task_name}", cache_policy=INPUTS + TASK_SOURCE,
      persist_result=True)
def recover_labels(task_name: str, demo_paths: list[Path], code_version: str) -> dict[str, list[list[int]]]:
    """Commanded and recovered plan vectors of each demo, in ``demo_paths`` order.

    Cached on the demo paths and ``code_version``; demo files are written once and never change.
    """
    plb = load_plb()
    commanded, recovered = [], []
    for path in demo_paths:
        demo = load_demo(path)
        commanded.append(np.asarray(demo.plan, dtype=int).tolist())
        recovered.append(np.asarray(recover_plan(demo, plb).plan, dtype=int).tolist())
    return {"commanded": commanded, "recovered": recovered}


@task(name="labels", cache_policy=NO_CACHE)
def labels_stage(synthesis: Synthesis, code_version: str) -> Labels:
    """Recover every task's labels and log the agreement per Representation-Space dimension."""
    import mlflow  # heavy: mlflow

    plb = load_plb()
    by_task = {}
    fractions: dict[str, np.ndarray] = {}
    with tracking.child_run("labels"):
        for name, paths in synthesis.demo_paths.items():
            by_task[name] = labels = recover_labels(name, paths, code_version)
            frac = agreement(np.array(labels["commanded"]), np.array(labels["recovered"]))
            unacted = task_class(name).unacted_dims
            mlflow.log_metrics({f"{name}/agreement/{dim}": float(f) for dim, f in zip(plb.dim_names, frac)}
                               | {f"{name}/agreement/acted_mean": acted_mean(frac, plb, unacted)})
            mlflow.log_dict(labels, f"{name}_labels.json")
            print(f"{name} label agreement:\n" + format_agreement(frac, len(paths), plb, unacted))
            fractions[name] = frac
    publish_table("label-agreement", [
        {"dimension": f"a{i} {dim}", **{name: round(float(f[i]), 3) for name, f in fractions.items()}}
        for i, dim in enumerate(plb.dim_names)],
        "Share of each task's demos whose recovered label equals the commanded plan, per dimension")
    return Labels(by_task)
