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

import numpy as np

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


EXPERIMENT_KIND_TAG = "mlflow.experimentKind"
"""The experiment tag through which MLflow 3 marks an experiment as GenAI or model development."""
MODEL_DEVELOPMENT = "custom_model_development"
"""Its value for model training (the UI's ``ExperimentKind.CUSTOM_MODEL_DEVELOPMENT``)."""
UI_RUNS_QUERY = "workflowType=machine_learning"
"""The query that opens MLflow 3.17's UI on an experiment's runs table: that UI picks an experiment's first page
from its own GenAI / Model training switch (this query, else the browser's last choice, GenAI at first), not
from the experiment's tag."""


def runs_page_url(experiment_id: str, ui: str = "http://127.0.0.1:5000") -> str:
    """The address of ``experiment_id``'s runs table in an ``mlflow ui`` served at ``ui``."""
    return f"{ui}/#/experiments/{experiment_id}?{UI_RUNS_QUERY}"


def configure(experiment: str = "prl") -> str:
    """Point MLflow at the project store and select ``experiment``; return the URI.

    Creates the experiment with an absolute artifact location beside the store when it does not exist yet,
    and tags it (or an existing one that lacks the tag) as a model-development experiment
    (``EXPERIMENT_KIND_TAG``; MLflow 3.17's UI opens it on its runs at :func:`runs_page_url`).
    """
    import mlflow  # heavy: mlflow

    uri = resolve_tracking_uri()
    mlflow.set_tracking_uri(uri)
    found = mlflow.get_experiment_by_name(experiment)
    if found is None:
        location = default_artifact_location() if uri == default_tracking_uri() else None
        mlflow.create_experiment(experiment, artifact_location=location, tags={EXPERIMENT_KIND_TAG: MODEL_DEVELOPMENT})
    elif found.tags.get(EXPERIMENT_KIND_TAG) != MODEL_DEVELOPMENT:
        mlflow.MlflowClient().set_experiment_tag(found.experiment_id, EXPERIMENT_KIND_TAG, MODEL_DEVELOPMENT)
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


NO_PICKLE_ENV = "MLFLOW_ALLOW_PICKLE_DESERIALIZATION"
"""MLflow's switch for unpickling on load (true by default); false makes it check a pt2 archive first."""


def log_exported_model(module: Any, name: str, x_example: np.ndarray, registered_model_name: str) -> Any:
    """Log the torch ``module`` as an MLflow model in the ``pt2`` format and register it; return the model info.

    ``pt2`` is ``torch.export``: the graph as JSON and the weights as raw tensor bytes, so loading it needs no
    pickle (unlike MLflow's ``pickle`` format, which runs whatever the file holds). The export traces
    ``module`` on ``x_example`` (float32 rows; at least 2, so that the batch dimension stays dynamic), which is
    also the signature's input example."""
    import mlflow  # heavy: mlflow
    import torch  # heavy: torch
    from mlflow.models import infer_signature

    x = np.ascontiguousarray(x_example, dtype=np.float32)
    if x.ndim != 2 or len(x) < 2:
        raise ValueError(f"x_example must hold at least 2 rows (a batch of 1 fixes the batch size), got {x.shape}")
    module.eval()
    with torch.no_grad():
        y = module(torch.as_tensor(x)).numpy()
    return mlflow.pytorch.log_model(module, name=name, signature=infer_signature(x, y), input_example=x,
                                    serialization_format="pt2", registered_model_name=registered_model_name)


@contextlib.contextmanager
def no_pickle() -> Iterator[None]:
    """Within the block MLflow unpickles nothing: ``NO_PICKLE_ENV`` is false, so a ``pickle``-format model is
    refused and a ``pt2`` archive is loaded only if every record is JSON, text or raw tensor data (MLflow checks
    this before ``torch.export.load``, which would otherwise unpickle a record a tampered archive marks so)."""
    before = os.environ.get(NO_PICKLE_ENV)
    os.environ[NO_PICKLE_ENV] = "false"
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(NO_PICKLE_ENV, None)
        else:
            os.environ[NO_PICKLE_ENV] = before


def load_exported_model(model_uri: str) -> Any:
    """The torch module of a ``pt2`` model logged by :func:`log_exported_model`, loaded under :func:`no_pickle`
    (MlflowException, and nothing run, for a model that would need unpickling)."""
    import warnings

    import mlflow  # heavy: mlflow

    with no_pickle(), warnings.catch_warnings():
        # torch.export.load makes the archive's raw weight bytes tensors without a copy and says so once; the
        # reloaded module is only evaluated
        warnings.filterwarnings("ignore", message="The given buffer is not writable", category=UserWarning)
        return mlflow.pytorch.load_model(model_uri)
