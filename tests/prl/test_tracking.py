"""The MLflow store is one absolute place, whatever the working directory."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from prl import tracking

REPO = Path(__file__).resolve().parents[2]


def _run_py(code: str, cwd: Path, env_extra: dict[str, str] | None = None, drop: tuple[str, ...] = ()) -> str:
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env["PYTHONPATH"] = str(REPO)
    env.update(env_extra or {})
    res = subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True,
                         check=True, timeout=300)
    return res.stdout.strip().splitlines()[-1]


def test_default_uri_is_absolute_repo_root_from_any_cwd(tmp_path: Path) -> None:
    out = _run_py("from prl import tracking; print(tracking.resolve_tracking_uri())", cwd=tmp_path,
                  drop=("MLFLOW_TRACKING_URI",))
    assert out == f"sqlite:///{REPO / 'mlflow.db'}"
    assert tracking.default_tracking_uri() == out


def test_env_var_overrides(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "sqlite:////tmp/elsewhere.db")
    assert tracking.resolve_tracking_uri() == "sqlite:////tmp/elsewhere.db"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "")
    assert tracking.resolve_tracking_uri() == tracking.default_tracking_uri()


def test_runs_from_two_directories_land_in_one_store(tmp_path: Path) -> None:
    store = tmp_path / "store.db"
    uri = f"sqlite:///{store}"
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    log = (
        "import mlflow; from prl import tracking; tracking.configure('t');"
        "import sys\n"
        "with tracking.parent_run('p', params={'x': {'y': 1}}) as p:\n"
        "    with tracking.child_run('c') as c:\n"
        "        mlflow.log_metric('m', 2.0)\n"
        "print(p.info.run_id)"
    )
    run_a = _run_py(log, cwd=a, env_extra={"MLFLOW_TRACKING_URI": uri})
    run_b = _run_py(log, cwd=b, env_extra={"MLFLOW_TRACKING_URI": uri})
    count = (
        f"import mlflow; mlflow.set_tracking_uri({uri!r});"
        "runs = mlflow.search_runs(experiment_names=['t']);"
        "print(len(runs), sorted(runs['params.x.y'].dropna().tolist()),"
        " int(runs['tags.mlflow.parentRunId'].notna().sum()))"
    )
    out = _run_py(count, cwd=tmp_path)
    assert out == "4 ['1', '1'] 2"  # 2 parents (with flattened param) + 2 children
    assert run_a != run_b
    assert not (a / "mlruns").exists() and not (b / "mlruns").exists()


def test_flatten_params_nested_dataclass() -> None:
    from dataclasses import dataclass, field

    @dataclass
    class Inner:
        lr: float = 0.5

    @dataclass
    class Outer:
        name: str = "x"
        inner: Inner = field(default_factory=Inner)

    assert tracking.flatten_params(Outer()) == {"name": "x", "inner.lr": "0.5"}


def test_experiments_are_model_development_and_the_runs_page_link_opens_them(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every experiment the project creates, or finds without it, carries MLflow's model-development kind."""
    import mlflow

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'store.db'}")
    tracking.configure("fresh")
    assert mlflow.get_experiment_by_name("fresh").tags[tracking.EXPERIMENT_KIND_TAG] == "custom_model_development"
    old = mlflow.create_experiment("older")  # made before the tag existed
    assert tracking.EXPERIMENT_KIND_TAG not in mlflow.get_experiment(old).tags
    tracking.configure("older")
    assert mlflow.get_experiment(old).tags[tracking.EXPERIMENT_KIND_TAG] == "custom_model_development"
    # the value is the one this MLflow's UI knows, and the runs page's query the switch it reads first (its bundled
    # JavaScript names the kinds and takes the workflow type from the query before the browser's last choice)
    ui = "".join(f.read_text(errors="ignore") for f in
                 (Path(mlflow.__file__).parent / "server" / "js" / "build" / "static" / "js").glob("main.*.js"))
    assert 'CUSTOM_MODEL_DEVELOPMENT="custom_model_development"' in ui
    assert 'e.MACHINE_LEARNING="machine_learning"' in ui and 'e.get("workflowType")' in ui
    assert tracking.runs_page_url("7") == "http://127.0.0.1:5000/#/experiments/7?workflowType=machine_learning"


def _tiny_net():
    import torch

    torch.manual_seed(0)
    return torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.BatchNorm1d(8), torch.nn.ReLU(),
                               torch.nn.Linear(8, 3)).eval()


class _OpenOnLoad:
    """Pickles as a call of ``open(path, "w")``: unpickling it creates the file (a harmless stand-in for a
    payload that runs any code)."""

    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self):
        return (open, (self.path, "w"))


def test_models_log_without_pickle_and_a_tampered_one_is_refused(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """``pt2`` models reload to the same outputs at another batch size, with no pickle warning (MLflow warns
    on a ``pickle`` model, and ``load_exported_model`` refuses one); a copy whose example-input record was
    replaced by a pickle payload, which MLflow's default load runs, is refused by
    ``load_exported_model`` before anything in it runs."""
    import logging
    import pickle
    import shutil
    import zipfile

    import mlflow
    import numpy as np
    import torch

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'store.db'}")
    tracking.configure("models")
    net = _tiny_net()
    x = np.random.default_rng(1).normal(size=(5, 4)).astype(np.float32)
    warnings: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: warnings.append(record.getMessage())
    logging.getLogger("mlflow").addHandler(handler)
    try:
        with mlflow.start_run():
            info = tracking.log_exported_model(net, "net", x[:2], "tiny")
            assert not [w for w in warnings if "Pickle" in w]
            pickled = mlflow.pytorch.log_model(net, name="pickled", serialization_format="pickle")
            assert [w for w in warnings if "Pickle" in w]  # what the project's models no longer cause
    finally:
        logging.getLogger("mlflow").removeHandler(handler)
    with pytest.raises(mlflow.exceptions.MlflowException, match="pickle is disallowed"):
        tracking.load_exported_model(pickled.model_uri)
    reloaded = tracking.load_exported_model(info.model_uri)
    with torch.no_grad():
        assert np.array_equal(reloaded(torch.as_tensor(x)).numpy(), net(torch.as_tensor(x)).numpy())  # batch 5
    with pytest.raises(ValueError, match="at least 2 rows"):
        tracking.log_exported_model(net, "net", x[:1], "tiny")

    local = Path(mlflow.artifacts.download_artifacts(info.model_uri, dst_path=str(tmp_path / "model")))
    tampered = tmp_path / "tampered"
    shutil.copytree(local, tampered)
    marker = tmp_path / "payload-ran"
    payload = pickle.dumps(_OpenOnLoad(str(marker)), protocol=2)
    with zipfile.ZipFile(local / "data" / "model.pt2") as src, \
            zipfile.ZipFile(tampered / "data" / "model.pt2", "w") as dst:
        assert any(i.filename.endswith("data/sample_inputs/model.pt") for i in src.infolist())
        for item in src.infolist():
            dst.writestr(item, payload if item.filename.endswith("data/sample_inputs/model.pt") else src.read(item))
    with pytest.raises(mlflow.exceptions.MlflowException, match="not a pickle-free payload"):
        tracking.load_exported_model(str(tampered))
    assert not marker.exists()
    # MLflow's default (pickle allowed) runs it before failing: the payload is real
    monkeypatch.delenv(tracking.NO_PICKLE_ENV, raising=False)
    with pytest.raises(RuntimeError, match="deserializing"):
        mlflow.pytorch.load_model(str(tampered))
    assert marker.exists()
