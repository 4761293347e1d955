"""The pipeline flow runs for real (Prefect ephemeral API, MLflow sqlite) and records what happened."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _pipeline(tmp_path: Path, *args: str, module: str = "flows.full_pipeline") -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env.update({"MLFLOW_TRACKING_URI": f"sqlite:///{tmp_path / 'mlflow.db'}", "PREFECT_HOME": str(tmp_path / "prefect"),
                "PREFECT_SERVER_ANALYTICS_ENABLED": "false", "XDG_RUNTIME_DIR": env.get("XDG_RUNTIME_DIR", "/tmp")})
    return subprocess.run([sys.executable, "-m", module, *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=900, check=False)


#: Prints the flow-run graph as Prefect's UI draws it: one "upstream -> downstream" line per edge between the
#: pipeline's task runs and subflow runs (a task's inputs that are another run's result); then one line
#: "artifact {key: table rows or markdown}" of the keyed artifacts, as the UI's Artifacts page lists them.
_GRAPH = r"""
import asyncio, json, re
from prefect.client.orchestration import get_client

async def main():
    async with get_client() as client:
        tasks, flows = await client.read_task_runs(), await client.read_flow_runs()
        flow_names = {f.flow_id: (await client.read_flow(f.flow_id)).name for f in flows}
        label = {str(t.id): re.sub(r"-([0-9a-f]{3}|[0-9]+)$", "", t.name) for t in tasks}
        for f in flows:  # a subflow: its wrapper task run and its flow run both read as the flow's name
            label[str(f.id)] = flow_names[f.flow_id]
            if f.parent_task_run_id:
                label[str(f.parent_task_run_id)] = flow_names[f.flow_id]
        for t in tasks:
            for inputs in t.task_inputs.values():
                for i in inputs:
                    if getattr(i, "id", None) is not None and str(i.id) in label:
                        print(f"{label[str(i.id)]} -> {label[str(t.id)]}")
        artifacts = await client.read_artifacts()
        print("artifact " + json.dumps({a.key: json.loads(a.data) if a.type == "table" else a.data
                                        for a in artifacts if a.key}))

asyncio.run(main())
"""


def test_bad_config_fails_before_work(tmp_path: Path) -> None:
    res = _pipeline(tmp_path, "--tasks", "hammer,hamer", "--output-dir", str(tmp_path / "out"))
    assert res.returncode == 2
    assert "unknown task 'hamer'" in res.stderr
    assert not (tmp_path / "mlflow.db").exists() and not (tmp_path / "out").exists()


@pytest.mark.sim
@pytest.mark.integration
def test_pipeline_tracks_parent_and_children(tmp_path: Path) -> None:
    res = _pipeline(tmp_path, "--tasks", "hammer,sweep", "--eval-scenes", "2", "--no-render",
                    "--output-dir", str(tmp_path / "out"), "--demos-per-task", "3", "--n-shards", "1", "--workers", "1",
                    "--pn-epochs", "1", "--pn-shapes", "64", "--rn-epochs", "3", "--rn-eval-scenes", "1",
                    "--ln-timesteps", "16", "--ln-steps-per-update", "16", "--ln-n-envs", "1")
    assert res.returncode == 0, res.stderr[-3000:]
    import mlflow

    mlflow.set_tracking_uri(f"sqlite:///{tmp_path / 'mlflow.db'}")
    runs = mlflow.search_runs(experiment_names=["prl"])
    parents = runs[runs["tags.mlflow.parentRunId"].isna()]
    children = runs[runs["tags.mlflow.parentRunId"].notna()]
    assert len(parents) == 1
    assert set(children["tags.mlflow.runName"]) == {"assets", "trials-hammer", "trials-sweep", "synthesis", "labels",
                                                    "export", "pointnet", "features", "rn-train", "rn-eval",
                                                    "ln-hammer-physics-k3-seed0", "ln-sweep-physics-k3-seed0"}
    assert set(children["tags.mlflow.parentRunId"]) == {parents.iloc[0]["run_id"]}
    trials = children[children["tags.mlflow.runName"] == "trials-hammer"].iloc[0]
    # measured in simulation: the expert plan drives the nail on these two scenes
    assert trials["metrics.hammer/expert/success_rate"] == 1.0
    assert trials["metrics.hammer/expert/mean_nail_descent_cm"] > 0.5
    assert trials["metrics.hammer/uniform/n"] == 2
    sweep = children[children["tags.mlflow.runName"] == "trials-sweep"].iloc[0]
    assert sweep["metrics.sweep/expert/success_rate"] == 1.0 and sweep["metrics.sweep/expert/mean_cubes_in_zone"] > 3
    assert parents.iloc[0]["params.tasks"] == "('hammer', 'sweep')"
    assert (tmp_path / "out" / "run-seed0" / "hammer_trial_rates.png").stat().st_size > 10_000
    synthesis = children[children["tags.mlflow.runName"] == "synthesis"].iloc[0]
    for task in ("hammer", "sweep"):
        assert synthesis[f"metrics.{task}/successes"] == 3.0
        assert synthesis[f"metrics.{task}/attempts"] >= 3.0 and synthesis[f"metrics.{task}/errors"] == 0.0
    demos = list((tmp_path / "out" / "synthesis").rglob("ep*.npz"))
    assert len(demos) == 6
    export = children[children["tags.mlflow.runName"] == "export"].iloc[0]
    assert export["metrics.episodes"] == 6.0
    from prl.export_check import validate_lerobot
    from prl.export_schema import VideoSpec

    # the quick profile's dataset carries both cameras' video (lerobot's default codec), and reloads with it
    report = validate_lerobot(tmp_path / "out" / "datasets" / "hammer-sweep-seed0", "prl/hammer-sweep",
                              video=VideoSpec())
    assert report.n_episodes == 6 and report.n_frames == export["metrics.frames"] > 0
    assert report.video_codec == "av1" and export["params.video"] == "128x128 at 10 pictures/s, av1"
    assert export["metrics.video_render_seconds"] > 0
    assert export["params.dataset_digest"] and len(export["params.dataset_digest"]) == 16
    info = json.loads((tmp_path / "out" / "datasets" / "hammer-sweep-seed0" / "meta" / "info.json").read_text())
    assert info["features"]["observation.environment_state"]["shape"] == [52]  # what a state-based policy reads
    experiment = mlflow.get_experiment_by_name("prl")
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"  # the UI opens on the runs
    figures = {a.path for a in mlflow.MlflowClient().list_artifacts(trials["run_id"])}
    assert "hammer_trial_rates.png" in figures

    # RN stages: scenes split by seed into train and held out; the registered model reloads to the same logits
    rn = children[children["tags.mlflow.runName"] == "rn-train"].iloc[0]
    assert rn["metrics.n_train"] + rn["metrics.n_val"] == 6.0 and rn["metrics.n_val"] >= 1.0
    assert rn["metrics.registered_reload_max_abs_diff"] == 0.0
    for task in ("hammer", "sweep"):  # distinct plans of the task's (at most 3) training demos
        assert 1.0 <= rn[f"metrics.{task}/plan_library_size"] <= 3.0
    assert 0.0 <= rn["metrics.val_accuracy/grasp_pattern"] <= 1.0
    history = mlflow.tracking.MlflowClient().get_metric_history(rn["run_id"], "rn/loss_ce")
    assert [m.step for m in history] == [0, 1, 2]
    versions = mlflow.tracking.MlflowClient().search_model_versions("name='prl-rn'")
    assert len(versions) == 1
    assert (tmp_path / "out" / "run-seed0" / "rn_probabilities.png").stat().st_size > 10_000
    ev = children[children["tags.mlflow.runName"] == "rn-eval"].iloc[0]
    for split in ("train_ranges", "wide_ranges"):
        for kind in ("rn", "rn_library", "rn_success", "prior", "expert"):
            assert ev[f"metrics.hammer/{split}/{kind}_success_rate"] in (0.0, 1.0)
            # one scene: the Wilson interval of 0/1 is [0, .79], of 1/1 [.21, 1]
            assert ev[f"metrics.hammer/{split}/{kind}_ci95_high"] - ev[f"metrics.hammer/{split}/{kind}_ci95_low"] \
                == pytest.approx(0.7935, abs=1e-3)
    assert len(list((tmp_path / "out" / "models").glob("pointnet-*.pt"))) == 1

    # the Prefect flow-run graph is the pipeline's DAG: each stage's inputs are the earlier stages' results
    env = dict(os.environ, PREFECT_HOME=str(tmp_path / "prefect"), PREFECT_SERVER_ANALYTICS_ENABLED="false")
    graph = subprocess.run([sys.executable, "-c", _GRAPH], env=env, capture_output=True, text=True, timeout=300,
                           check=False)
    assert graph.returncode == 0, graph.stderr[-3000:]
    edges = {line for line in graph.stdout.splitlines() if " -> " in line}
    for edge in ("assets -> trials-hammer", "assets -> trials-sweep", "trials-hammer -> synthesis",
                 "trials-sweep -> synthesis", "synthesis -> labels", "labels -> export", "synthesis -> export",
                 "assets -> pointnet", "export -> features", "pointnet -> features", "features -> rn-train",
                 "rn-train -> rn-eval", "rn-eval -> ln", "features -> ln"):
        assert edge in edges, (edge, sorted(edges))
    # the run's keyed artifacts, as the Prefect UI's Artifacts page lists them
    artifacts = dict(line.split(" ", 1) for line in graph.stdout.splitlines() if line.startswith("artifact "))
    tables = json.loads(artifacts["artifact"])
    assert set(tables) == {"trial-rates-hammer", "trial-rates-sweep", "synthesis-yield", "synthesis-rounds",
                           "label-agreement", "rn-success", "ln-success", "pipeline-summary"}, sorted(tables)
    assert [row["plan kind"] for row in tables["trial-rates-hammer"]] == ["expert", "prior", "uniform"]
    assert tables["trial-rates-hammer"][0]["successes"] == "2/2" and tables["trial-rates-hammer"][0]["95% CI"]
    assert {row["task"]: row["demos kept"] for row in tables["synthesis-yield"]} == {"hammer": 3, "sweep": 3}
    # the adaptive proposal's record: one row per task and round, the rounds' attempts adding up to the yield table's
    rounds = tables["synthesis-rounds"]
    for row in tables["synthesis-yield"]:
        mine = [r for r in rounds if r["task"] == row["task"]]
        assert [r["round"] for r in mine] == list(range(len(mine))) and mine[-1]["demos kept"] == 3
        assert sum(r["attempts"] for r in mine) == row["attempts"]
    assert [row["dimension"][:2] for row in tables["label-agreement"]] == ["a0", "a1", "a2", "a3", "a4", "a5"]
    assert len(tables["rn-success"]) == 2 * 2 * 5  # tasks x splits x (3 decodings + 2 baselines)
    assert {row["task"] for row in tables["ln-success"]} == {"hammer", "sweep"}
    assert "prl-full-pipeline: profile quick" in tables["pipeline-summary"]
    assert "two camera videos 128x128, 10 pictures/s (av1)" in tables["pipeline-summary"]

    # LN: one child run per task, pre-trained on the task's 3 demos, one A2C update of 16 plan episodes
    client = mlflow.tracking.MlflowClient()
    for task in ("hammer", "sweep"):
        ln = children[children["tags.mlflow.runName"] == f"ln-{task}-physics-k3-seed0"].iloc[0]
        assert ln["params.ln.demo_steps"] == "3" and ln["params.ln.steps_per_update"] == "16"
        assert ln["params.ln.learning_rate"] == "0.0007" and ln["params.sb3.vf_coef"] == "0.5"
        assert [m.step for m in client.get_metric_history(ln["run_id"], "ln/success_rate")] == [16]
        assert 0.0 <= ln["metrics.ln/success_rate"] <= 1.0 and ln["metrics.ln/frames"] > 16 * 700
        assert len(client.get_metric_history(ln["run_id"], "ln/pretrain/actor_loss")) == 10  # 10 epochs x 1 batch
        assert ln["metrics.ln/eval/success_rate"] in (0.0, 1.0) and ln["metrics.ln/eval/errors"] == 0.0
        assert ln["metrics.registered_reload_action_mismatches"] == 0.0
    assert len(client.search_model_versions("name='prl-ln'")) == 2

    # the saved checkpoint, evaluated on its own by flows.evaluate_rn on the pipeline's first eval scene,
    # finds its PointNet by digest and reproduces the pipeline's plans and outcomes exactly
    res = _pipeline(tmp_path, "--rn-path", str(tmp_path / "out" / "models" / "rn-seed0.pt"), "--first-seed", "10000000",
                    "--scenes", "1", "--decodings", "rn,rn_library", module="flows.evaluate_rn")
    assert res.returncode == 0, res.stderr[-3000:]
    runs = mlflow.search_runs(experiment_names=["prl"], filter_string="tags.mlflow.runName = 'rn-eval'")
    alone = runs[runs["tags.mlflow.parentRunId"].isna()].iloc[0]
    assert alone["params.first_seed"] == "10000000" and alone["params.decodings"] == "rn,rn_library"
    assert alone["params.pointnet_path"].endswith(".pt") and "pointnet-" in alone["params.pointnet_path"]
    name = "hammer_train_ranges_rn_eval.json"
    before = json.loads(Path(mlflow.artifacts.download_artifacts(run_id=ev["run_id"], artifact_path=name,
                                                                 dst_path=str(tmp_path / "a"))).read_text())
    after = json.loads(Path(mlflow.artifacts.download_artifacts(run_id=alone["run_id"], artifact_path=name,
                                                                dst_path=str(tmp_path / "b"))).read_text())
    assert set(after) == {"rn", "rn_library", "prior", "expert"}
    for kind in after:
        assert after[kind] == before[kind], kind
