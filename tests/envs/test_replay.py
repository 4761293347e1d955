"""A dataset's ``action`` stream replayed open loop in the joint-control environment reproduces its demos, and a
LeRobot policy (ACT) trains on the dataset offline and acts in that environment (``envs.replay``,
``prl.imitation``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

TASKS = ("hammer", "unscrew")
SEEDS = (11, 12)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A dataset of the expert plan's full-length episodes on two scenes of each of ``TASKS``."""
    pytest.importorskip("mani_skill")
    from envs.executor import PlanExecutor
    from envs.tasks import make_env, task_class
    from prl.demo import from_episode, save_demo
    from prl.export import export_lerobot
    from prl.plb import load_plb

    out = tmp_path_factory.mktemp("replay")
    paths = []
    for task in TASKS:
        env = make_env(task)
        try:
            executor = PlanExecutor(env)
            for seed in SEEDS:
                result = executor.run(task_class(task).expert_plan, seed=seed)
                demo = from_episode(task, seed, load_plb().texts(task)[0], result, env)
                paths.append(save_demo(demo, out / "demos" / f"{task}-{seed}.npz"))
        finally:
            env.close()
    export_lerobot(paths, out / "ds", repo_id="prl/replay-test")
    return out / "ds"


@pytest.mark.sim
def test_replayed_actions_reproduce_the_demos(dataset: Path) -> None:
    from envs.replay import replay_dataset, replay_table

    outcomes = replay_dataset(dataset, per_task=2, progress=False)
    assert [(o.task, o.seed) for o in outcomes] == [(t, s) for t in TASKS for s in SEEDS]
    assert all(o.recorded_success for o in outcomes)  # the expert succeeds on these scenes
    assert all(o.reproduced for o in outcomes), outcomes
    for o in outcomes:  # the same measure within 25 %, every joint within 0.3 rad (or m) of the record at all times
        assert o.measure == pytest.approx(o.recorded_measure, rel=0.25), o
        assert o.max_joint_deviation < 0.3, o
    assert "| hammer | 2 | 2 | 1.00 |" in "\n".join(replay_table(outcomes))


@pytest.mark.sim
def test_unknown_task_in_a_replay_is_named(dataset: Path) -> None:
    from envs.replay import replay_dataset

    with pytest.raises(ValueError, match="holds no 'sweep' episode"):
        replay_dataset(dataset, per_task=1, tasks=["sweep"], progress=False)


def test_imitation_config_names_bad_values() -> None:
    from prl.imitation import ImitationConfig, policy_config

    with pytest.raises(ValueError, match="policy must be one of"):
        ImitationConfig(policy="diffusion")
    with pytest.raises(ValueError, match="n_action_steps \\(30\\) must not exceed chunk_size \\(25\\)"):
        ImitationConfig(n_action_steps=30)
    with pytest.raises(ValueError, match="steps must be an integer >= 1, got 0"):
        ImitationConfig(steps=0)
    old = {"observation.state": {"shape": [60]}, "action": {"shape": [30]}}  # exported before environment_state
    with pytest.raises(ValueError, match="no 'observation.environment_state' feature"):
        policy_config(ImitationConfig(), old)


@pytest.mark.sim
@pytest.mark.train
def test_act_trains_on_the_dataset_and_acts_in_the_joint_env(dataset: Path, tmp_path: Path) -> None:
    from envs.joint_env import run_target_policy
    from prl.imitation import ImitationActor, ImitationConfig, task_episodes, train_imitation

    cfg = ImitationConfig(steps=4, batch_size=8, dim_model=64, dim_feedforward=128, n_heads=4, log_every=2)
    episodes = task_episodes(dataset, "hammer")
    assert episodes == [0, 1]
    result = train_imitation(dataset, cfg, tmp_path / "im", episodes, progress=False)
    assert [r["step"] for r in result.losses] == [2.0, 4.0] and all(np.isfinite(r["loss"]) for r in result.losses)
    assert result.frames == 2 * 150
    saved = sorted(p.name for p in result.policy_dir.iterdir())
    assert "model.safetensors" in saved and "config.json" in saved and not any(p.endswith(".pkl") for p in saved)
    actor = ImitationActor(result.policy_dir)
    targets = actor(np.zeros(60), np.zeros(52))
    assert targets.shape == (30,) and np.all(np.isfinite(targets))
    (outcome,) = run_target_policy("hammer", actor, [10_000_000], progress=False)
    assert outcome.error == "" and isinstance(outcome.success, bool) and np.isfinite(outcome.measure)
    with pytest.raises(FileNotFoundError, match="no trained policy"):
        ImitationActor(tmp_path / "nowhere")


@pytest.mark.sim
@pytest.mark.train
@pytest.mark.integration
def test_the_imitation_flow_trains_registers_and_rolls_out(dataset: Path, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    """``python -m flows.imitation`` as a user runs it: a parent run with its two child runs, the loss per step,
    the policy registered as ``prl-imitation`` (lerobot's files, no pickle), the rollout's success rate."""
    import os
    import subprocess
    import sys

    import mlflow

    repo = Path(__file__).resolve().parents[2]
    env = {**os.environ, "MLFLOW_TRACKING_URI": f"sqlite:///{tmp_path / 'mlflow.db'}",
           "PREFECT_HOME": str(tmp_path / "prefect"), "PREFECT_SERVER_ANALYTICS_ENABLED": "false"}
    args = ["--dataset-root", str(dataset), "--task", "unscrew", "--steps", "3", "--batch-size", "8", "--dim-model",
            "64", "--dim-feedforward", "128", "--n-heads", "4", "--log-every", "1", "--eval-scenes", "1",
            "--output-dir", str(tmp_path / "im")]
    res = subprocess.run([sys.executable, "-m", "flows.imitation", *args], cwd=repo, env=env, capture_output=True,
                         text=True, timeout=900, check=False)
    assert res.returncode == 0, res.stderr[-3000:]
    mlflow.set_tracking_uri(env["MLFLOW_TRACKING_URI"])
    runs = mlflow.search_runs(experiment_names=["prl"])
    names = set(runs["tags.mlflow.runName"])
    assert {"imitation-unscrew", "imitation-train", "imitation-rollout"} <= names
    train = runs[runs["tags.mlflow.runName"] == "imitation-train"].iloc[0]
    rollout = runs[runs["tags.mlflow.runName"] == "imitation-rollout"].iloc[0]
    history = mlflow.MlflowClient().get_metric_history(train["run_id"], "imitation/loss")
    assert [m.step for m in history] == [1, 2, 3] and train["params.steps"] == "3"
    assert rollout["metrics.imitation/success_rate"] in (0.0, 1.0)
    (version,) = mlflow.MlflowClient().search_model_versions("name='prl-imitation'")
    files = {Path(p).name for p in (Path(mlflow.artifacts.download_artifacts(f"models:/prl-imitation/{version.version}"))
                                    .iterdir())}
    assert {"model.safetensors", "config.json"} <= files and not any(f.endswith((".pkl", ".pt")) for f in files)
    from flows.imitation import main  # bad input is named before any flow or MLflow run starts

    assert main([*args, "--task", "hamer"]) == 2 and "unknown task 'hamer'" in capsys.readouterr().err
    assert main([*args, "--demos", "0"]) == 2 and "demos must be >= 1" in capsys.readouterr().err
    import json
    import shutil

    old = shutil.copytree(dataset, tmp_path / "old")  # a dataset exported before observation.environment_state
    info = json.loads((old / "meta" / "info.json").read_text())
    del info["features"]["observation.environment_state"]
    (old / "meta" / "info.json").write_text(json.dumps(info))
    assert main([*args, "--dataset-root", str(old)]) == 2
    assert "no 'observation.environment_state' feature" in capsys.readouterr().err
    assert len(mlflow.search_runs(experiment_names=["prl"])) == len(runs)


@pytest.mark.sim
def test_the_synthesis_replay_check_keeps_only_demos_that_replay(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """``replay_check``: a kept demo replays (checked again in a fresh env); the same demo with its targets held at
    the first record does not (the hammer never swings); and an attempt that succeeded but did not replay is
    recorded as failed, ``replayed: false``, without a demo file, and counted by the yield report."""
    from envs import synthesis
    from envs.joint_env import JointControlEnv
    from envs.replay import demo_replays
    from prl.demo import load_demo

    spec = synthesis.ShardSpec(task="hammer", shard=0, n_success=1, run_seed=5, out_dir=tmp_path / "checked",
                               max_attempts=8, replay_check=True)
    result = synthesis.run_shard(spec)
    assert result.successes == 1 and len(result.demo_paths) == 1
    demo = load_demo(result.demo_paths[0])
    env = JointControlEnv("hammer", steps=int(np.asarray(demo.stage).shape[0]))
    try:
        assert demo_replays(env, demo)
        held = np.repeat(np.asarray(demo.target)[:1], len(demo.target), axis=0)
        demo.arrays["target"] = held
        assert not demo_replays(env, demo)
    finally:
        env.close()

    monkeypatch.setattr(synthesis, "demo_replays", lambda env, demo: False)
    refused = synthesis.ShardSpec(task="hammer", shard=0, n_success=1, run_seed=5, out_dir=tmp_path / "refused",
                                  max_attempts=3, replay_check=True)
    out = synthesis.run_shard(refused)
    rows = synthesis.read_attempts(refused.dir)
    assert out.successes == 0 and not out.demo_paths and not list(refused.dir.glob("ep*.npz"))
    not_replayed = [r for r in rows if r.get("replayed") is False]
    assert not_replayed and all(not r["success"] and r["measure"] > 0 for r in not_replayed)
    assert synthesis.yield_report(tmp_path / "refused", "hammer")["not_replayed"] == len(not_replayed)
