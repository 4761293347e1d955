"""MLflow tracking helpers: one store per checkout, parent and child runs.

The tracking URI is resolved once, at the entry point, by :func:`configure`:
``MLFLOW_TRACKING_URI`` when set, else ``sqlite:///<repo>/mlflow.db`` with
artifacts in ``<repo>/mlartifacts``. Both are absolute, so the same store is
used whatever the working directory is, and
``mlflow ui --backend-store-uri sqlite:///mlflow.db`` run at the repo root opens it.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Mapping
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

from prl.constants import REPO_ROOT


def default_tracking_uri(root: Path = REPO_ROOT) -> str:
    """The project's default store: an absolute sqlite URI at the repo root."""
    return f"sqlite:///{(root / 'mlflow.db').resolve()}"


def default_artifact_location(root: Path = REPO_ROOT) -> str:
    """Absolute directory for artifacts of experiments created by this project."""
    return (root / "mlartifacts").resolve().as_uri()


def resolve_tracking_uri() -> str:
    """``MLFLOW_TRACKING_URI`` if set (and non-empty), else the repo-root sqlite store."""
    return os.environ.get("MLFLOW_TRACKING_URI") or default_tracking_uri()


def configure(experiment: str = "prl") -> str:
    """Point MLflow at the project store and select ``experiment``; return the URI.

    Creates the experiment with an absolute artifact location beside the store
    when it does not exist yet.
    """
    import mlflow  # heavy: mlflow

    uri = resolve_tracking_uri()
    mlflow.set_tracking_uri(uri)
    if mlflow.get_experiment_by_name(experiment) is None:
        location = default_artifact_location() if uri == default_tracking_uri() else None
        mlflow.create_experiment(experiment, artifact_location=location)
    mlflow.set_experiment(experiment)
    return uri


def flatten_params(cfg: Any, prefix: str = "") -> dict[str, str]:
    """Flatten a (nested) dataclass or mapping to ``{"a.b": "value"}`` for ``log_params``."""
    if is_dataclass(cfg) and not isinstance(cfg, type):
        cfg = asdict(cfg)
    out: dict[str, str] = {}
    if isinstance(cfg, Mapping):
        for key, value in cfg.items():
            name = f"{prefix}.{key}" if prefix else str(key)
            if isinstance(value, Mapping) or (is_dataclass(value) and not isinstance(value, type)):
                out.update(flatten_params(value, name))
            else:
                out[name] = str(value)[:500]
    else:
        out[prefix or "value"] = str(cfg)[:500]
    return out


@contextlib.contextmanager
def parent_run(name: str, params: Any = None, tags: Mapping[str, str] | None = None) -> Iterator[Any]:
    """Start a top-level run (ending any stray active run first) and log ``params``."""
    import mlflow  # heavy: mlflow

    while mlflow.active_run() is not None:
        mlflow.end_run()
    with mlflow.start_run(run_name=name, tags=dict(tags or {})) as run:
        if params is not None:
            mlflow.log_params(flatten_params(params))
        yield run


@contextlib.contextmanager
def child_run(name: str, params: Any = None, parent_run_id: str | None = None) -> Iterator[Any]:
    """Start a nested run under the active run (or under ``parent_run_id``)."""
    import mlflow  # heavy: mlflow

    tags = {"mlflow.parentRunId": parent_run_id} if parent_run_id else None
    with mlflow.start_run(run_name=name, nested=parent_run_id is None, tags=tags) as run:
        if params is not None:
            mlflow.log_params(flatten_params(params))
        yield run
