"""Prefect task: recover the physical-law labels of demos from their recordings (Eqs 4-9)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from prefect import task
from prefect.cache_policies import INPUTS, TASK_SOURCE


@task(name="recover-labels", task_run_name="labels-{task_name}", cache_policy=INPUTS + TASK_SOURCE,
      persist_result=True)
def recover_labels(task_name: str, demo_paths: list[Path], code_version: str) -> dict[str, list[list[int]]]:
    """Commanded and recovered plan vectors of each demo, in ``demo_paths`` order.

    Cached on the demo paths and ``code_version``; demo files are written once and never change.
    """
    from prl.demo import load_demo
    from prl.label_recovery import recover_plan
    from prl.plb import load_plb

    plb = load_plb()
    commanded, recovered = [], []
    for path in demo_paths:
        demo = load_demo(path)
        commanded.append(np.asarray(demo.plan, dtype=int).tolist())
        recovered.append(np.asarray(recover_plan(demo, plb).plan, dtype=int).tolist())
    return {"commanded": commanded, "recovered": recovered}
