"""Shared set-up of the test suite.

Layout mirrors the packages: ``tests/prl`` (the library), ``tests/envs`` (the simulation side),
``tests/flows`` (Prefect stages, the LN sweep, the whole pipeline and its deployments), and the repository's
shape in ``tests/test_structure.py``. Markers (``pyproject.toml``): ``sim`` runs physics, ``train`` runs short
training, ``integration`` runs the whole system (a pipeline flow, deployments on a Prefect server).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

# SAPIEN's renderer wants a runtime directory even when nothing is rendered; set before any test imports it.
os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp/prl-runtime")
os.makedirs(os.environ["XDG_RUNTIME_DIR"], exist_ok=True)


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Stop Prefect's temporary API server (started by the first in-process flow or task run) now, while pytest's
    captured streams are open. Prefect stops it at interpreter exit otherwise, logging "Stopping temporary server"
    through its console handler, whose stream is by then pytest's closed capture file: a "Logging error"
    traceback at the end of every run that ran a flow. As Prefect's own test harness does, the workers that send
    logs and events to that server are drained first, so that none of them calls it once it is gone."""
    server_module = sys.modules.get("prefect.server.api.server")
    if server_module is None:  # prefect's server was never imported: nothing was started
        return
    server = server_module.SubprocessASGIServer()  # the default (port-less) one the ephemeral API uses
    if server.running:
        from prefect.events.worker import EventsWorker  # loaded along with the server module above
        from prefect.logging.handlers import APILogWorker

        APILogWorker.drain_all()
        EventsWorker.drain_all()
    server.stop()


@pytest.fixture(scope="module")
def make_task_env() -> Iterator[Callable[..., Any]]:
    """A factory of PRL task environments (``envs.tasks.make_env`` keyword arguments), each returned unwrapped
    and closed when the test module ends."""
    from envs.tasks import make_env  # heavy: loads the simulator (only tests that ask for a scene pay)

    made: list[Any] = []

    def make(task: str, **kwargs: Any) -> Any:
        gym_env = make_env(task, **kwargs)
        made.append(gym_env)
        return gym_env.unwrapped

    yield make
    for gym_env in made:
        gym_env.close()


@pytest.fixture(scope="module")
def executor(env: Any) -> Any:
    """A ``PlanExecutor`` on the test module's ``env`` fixture (a task's unwrapped environment)."""
    from envs.executor import PlanExecutor  # heavy: loads the simulator

    return PlanExecutor(env)


TINY_POINTNET = {"n_points": 64, "n_shapes": 48, "n_val": 16, "epochs": 1, "channels": (16, 32), "head": (256,), "seed": 5}
"""A PointNet small enough to build in a test (the plan environment only needs a fixed encoder)."""


@pytest.fixture(scope="session")
def pointnet_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An untrained ``TINY_POINTNET`` checkpoint: the plan environment and the LN encode scenes with it."""
    import torch  # heavy: torch (only tests that encode scenes pay)

    from prl.pointnet import PointNetConfig, PointNetEncoder, save_pointnet  # heavy: torch

    cfg = PointNetConfig(**TINY_POINTNET)
    torch.manual_seed(0)
    return save_pointnet(PointNetEncoder(cfg).eval(), cfg, tmp_path_factory.mktemp("pn") / "pn.pt")
