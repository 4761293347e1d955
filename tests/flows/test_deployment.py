"""The served deployments run on a real Prefect server, as a user runs them (``prefect deployment run``)."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PREFECT = str(Path(sys.executable).with_name("prefect"))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(check, timeout_s: float, what: str, procs: list[subprocess.Popen]) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        for p in procs:
            if p.poll() is not None:
                raise AssertionError(f"{what}: {p.args[:3]} exited with {p.returncode}: {p.stdout.read()[-3000:]}")
        try:
            if check():
                return
        except Exception:
            pass
        time.sleep(1.0)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


@pytest.mark.sim
@pytest.mark.integration
def test_quick_pipeline_deployment_runs_on_a_prefect_server(tmp_path: Path) -> None:
    port = _free_port()
    api = f"http://127.0.0.1:{port}/api"
    env = dict(os.environ, PREFECT_HOME=str(tmp_path / "prefect"), PREFECT_API_URL=api,
               PREFECT_SERVER_ANALYTICS_ENABLED="false", MLFLOW_TRACKING_URI=f"sqlite:///{tmp_path / 'mlflow.db'}",
               PREFECT_SERVER_DATABASE_CONNECTION_URL=f"sqlite+aiosqlite:///{tmp_path / 'prefect.db'}")
    env.pop("PREFECT_SERVER_API_PORT", None)
    procs: list[subprocess.Popen] = []
    try:
        procs.append(subprocess.Popen([PREFECT, "server", "start", "--host", "127.0.0.1", "--port", str(port)],
                                      cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True))
        _wait(lambda: urllib.request.urlopen(f"{api}/health", timeout=2).status == 200, 180, "the Prefect server", procs)
        procs.append(subprocess.Popen([sys.executable, "-m", "flows.serve"], cwd=REPO, env=env,
                                      stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True))
        names = ("prl-full-pipeline/quick", "prl-full-pipeline/paper", "prl-rn-eval/default", "prl-ln-ablation/default",
                 "prl-imitation/default")

        def served() -> bool:
            req = urllib.request.Request(f"{api}/deployments/filter", data=b"{}", method="POST",
                                         headers={"Content-Type": "application/json"})
            rows = json.loads(urllib.request.urlopen(req, timeout=5).read())
            flow_names = {r["flow_id"]: json.loads(urllib.request.urlopen(f"{api}/flows/{r['flow_id']}",
                                                                          timeout=5).read())["name"] for r in rows}
            return set(names) <= {f"{flow_names[r['flow_id']]}/{r['name']}" for r in rows}

        _wait(served, 240, "the served deployments", procs)
        overrides = {"tasks": ["hammer"], "eval_scenes": 1, "demos_per_task": 1, "n_shards": 1, "workers": 1,
                     "render": False, "train_rn": False, "output_dir": str(tmp_path / "out"),
                     "ln": {"timesteps": 128}}  # nested: merged over the quick profile's LN settings
        res = subprocess.run([PREFECT, "deployment", "run", "prl-full-pipeline/quick", "--param",
                              f"overrides={json.dumps(overrides)}", "--watch", "--watch-timeout", "900"],
                             cwd=REPO, env=env, capture_output=True, text=True, timeout=960, check=False)
        assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
        assert "Completed" in res.stdout, res.stdout[-3000:]
        # the run's keyed artifacts, read through the server's API as its Artifacts page does
        req = urllib.request.Request(f"{api}/artifacts/filter", data=b"{}", method="POST",
                                     headers={"Content-Type": "application/json"})
        artifacts = {a["key"]: a for a in json.loads(urllib.request.urlopen(req, timeout=10).read()) if a["key"]}
    finally:
        for p in reversed(procs):
            p.terminate()
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()

    # the flow run the server recorded, and the MLflow parent run it wrote, with its stage child runs
    import mlflow

    mlflow.set_tracking_uri(f"sqlite:///{tmp_path / 'mlflow.db'}")
    runs = mlflow.search_runs(experiment_names=["prl"])
    parents = runs[runs["tags.mlflow.parentRunId"].isna()]
    assert len(parents) == 1 and parents.iloc[0]["status"] == "FINISHED"
    assert parents.iloc[0]["params.demos_per_task"] == "1" and parents.iloc[0]["params.tasks"] == "('hammer',)"
    assert parents.iloc[0]["params.ln.timesteps"] == "128" and parents.iloc[0]["params.ln.n_envs"] == "2"
    children = set(runs[runs["tags.mlflow.parentRunId"].notna()]["tags.mlflow.runName"])
    assert children == {"assets", "trials-hammer", "synthesis", "labels", "export"}
    assert len(list((tmp_path / "out" / "synthesis").rglob("ep*.npz"))) == 1
    assert set(artifacts) == {"trial-rates-hammer", "synthesis-yield", "synthesis-rounds", "label-agreement",
                              "pipeline-summary"}
    assert all(artifacts[k]["type"] == "table" for k in set(artifacts) - {"pipeline-summary"})
    trial_rates = json.loads(artifacts["trial-rates-hammer"]["data"])
    assert [r["plan kind"] for r in trial_rates] == ["expert", "prior", "uniform"]
    assert [r["successes"].split("/")[1] for r in trial_rates] == ["1", "1", "1"]  # eval_scenes 1
    assert json.loads(artifacts["synthesis-yield"]["data"])[0]["demos kept"] == 1
    summary = artifacts["pipeline-summary"]
    assert summary["type"] == "markdown" and "prl-full-pipeline: profile quick" in summary["data"]
    assert parents.iloc[0]["run_id"] in summary["data"]  # it names the run's MLflow parent run
