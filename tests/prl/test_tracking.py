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
