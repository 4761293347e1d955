"""A dataset's ``action`` stream replayed open loop in the joint-control environment reproduces its demos, and a
LeRobot policy (ACT) trains on the dataset offline and acts in that environment (``envs.replay``,
``prl.imitation``)."""

from __future__ import annotations

import dataclasses
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


def test_imitation_draws_the_plan_space_points_demonstrations(tmp_path: Path) -> None:
    """``drawn_episodes`` names the dataset episodes whose transitions ``Demonstrations.take`` draws for the same K
    and seed (the task's episodes in the dataset's order), here told apart by their measures."""
    import json

    from prl.export_schema import SCENES_FILE
    from prl.imitation import drawn_episodes
    from prl.ln import Demonstrations

    tasks = ["hammer", "sweep", "hammer", "hammer", "sweep", "hammer", "hammer"]
    rows = [{"episode_index": i, "task": t, "seed": 100 + i, "outcome": {"m": float(i)}} for i, t in enumerate(tasks)]
    (tmp_path / SCENES_FILE).parent.mkdir(parents=True)
    (tmp_path / SCENES_FILE).write_text("".join(json.dumps(r) + "\n" for r in rows))
    hammer = [i for i, t in enumerate(tasks) if t == "hammer"]
    demos = Demonstrations(np.zeros((5, 2), np.float32), np.zeros((5, 6), np.int64), np.array(hammer, np.float32))
    for k, seed in ((3, 0), (5, 1), (1, 7)):
        assert [float(i) for i in drawn_episodes(tmp_path, "hammer", k, seed)] == list(demos.take(k, seed).reward)
    with pytest.raises(ValueError, match="demo_steps=6 must be between 1 and the 5 hammer episodes"):
        drawn_episodes(tmp_path, "hammer", 6, 0)


def test_the_replay_page_names_the_synthesis_runs_and_whether_they_were_checked() -> None:
    from envs.replay import ReplayOutcome, replay_page, synthesis_runs

    scenes = [{"source": f"/x/synthesis/{run}/hammer/shard000/ep000001.npz"} for run in ("b-replayed", "a-replayed")]
    assert synthesis_runs([*scenes, {"source": ""}]) == ["a-replayed", "b-replayed"]
    outcomes = [ReplayOutcome(0, "hammer", 1, True, True, 1.0, 1.1, 0.1),
                ReplayOutcome(1, "hammer", 2, True, False, 1.0, 0.2, 0.4)]
    page = replay_page(outcomes, "prl-replay ...", "ds", ["a-replayed", "b-replayed"])
    assert ("Its demos came from the synthesis runs `a-replayed`, `b-replayed` (a demo kept only when its replay "
            "succeeded at synthesis, `--replay-check`).") in page
    assert "| hammer | 2 | 1 | 0.50 | 0.2500 | 0.4000 |" in page and "All tasks: 1/2 = 0.50." in page
    assert "- hammer episode 1 (scene seed 2): True (1.00) -> False (0.20)" in page
    assert "synthesis run `plain`." in replay_page(outcomes, "c", "ds", ["plain"])


def test_the_replay_check_replays_the_actions_as_the_dataset_stores_them(monkeypatch: pytest.MonkeyPatch) -> None:
    """float32, as exported: replaying the float64 targets instead passed tweeze demos at synthesis that failed
    when replayed from the dataset (a 1e-7 difference decides such an episode)."""
    from types import SimpleNamespace

    from envs import replay

    seen = {}

    def fake(env, seed, actions, states, stages):
        seen.update(actions=actions, seed=seed, stages=stages)
        return True, 1.0, 0.0

    monkeypatch.setattr(replay, "replay_episode", fake)
    target = np.linspace(0.0, 1.0 + 1e-9, 90).reshape(3, 30)
    demo = SimpleNamespace(seed=7, target=target, qpos=np.zeros((3, 30)), qvel=np.zeros((3, 30)),
                           stage=np.array([[0], [1], [1]]))
    assert replay.demo_replays(None, demo)
    assert seen["actions"].dtype == np.float32 and seen["seed"] == 7 and seen["stages"].tolist() == [0, 1, 1]
    np.testing.assert_array_equal(seen["actions"], np.float32(np.concatenate([target[1:], target[-1:]])))


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
def test_act_trains_on_the_dataset_and_acts_in_the_joint_env_as_an_ln_point(dataset: Path, tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """An imitation point of the sweep (``flows.train_ln.run_imitation_point``): ACT trained on the drawn
    demonstrations' episodes, saved in lerobot's files (no pickle), rolled out in the joint-control env on an
    evaluation scene, its own MLflow run, and a committed summary that reloads (timesteps 0, its loss kept)."""
    import mlflow

    from flows.ln_results import committed_summary
    from flows.train_ln import LNPoint, LNSetup, run_imitation_point
    from prl import tracking
    from prl.config import LNConfig
    from prl.imitation import ImitationActor, ImitationConfig, drawn_episodes
    from prl.ln_summary import read_summary, write_summary

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    tracking.configure("prl")
    cfg = ImitationConfig(steps=4, batch_size=8, dim_model=64, dim_feedforward=128, n_heads=4, log_every=2)
    setup = LNSetup(demo_dir=tmp_path / "demos", pointnet_path=None, out_dir=tmp_path / "points",
                    eval_seeds=(10_000_000,), ln=LNConfig(), progress=False, dataset_root=dataset, imitation=cfg)
    point = LNPoint("hammer", "imitation", 2, 1)
    assert sorted(drawn_episodes(dataset, "hammer", 2, 1)) == [0, 1]
    summary = run_imitation_point(point, setup)
    assert [r["step"] for r in summary["loss"]] == [2.0, 4.0] and all(np.isfinite(r["loss"]) for r in summary["loss"])
    saved = sorted(p.name for p in Path(summary["checkpoint"]).iterdir())
    assert "model.safetensors" in saved and "config.json" in saved and not any(p.endswith(".pkl") for p in saved)
    (outcome,) = summary["eval"]["outcomes"]
    assert outcome["seed"] == 10_000_000 and outcome["error"] == "" and np.isfinite(outcome["measure"])
    run = mlflow.get_run(summary["run_id"])
    assert run.data.tags["ln_method"] == "imitation" and run.data.params["episodes"] == "2"
    assert run.data.params["imitation.seed"] == "1"  # the point's seed, not the config's
    assert run.data.metrics["imitation/steps"] == 4.0  # what the sweep's progress bar counts
    record = {"point": summary["point"], "timesteps": 0, "settings": {}, "code_version": "0" * 16,
              "dataset_digest": None}
    path = write_summary(tmp_path / "ln", committed_summary(summary, record, "t0", "t1", 1))
    assert path.name == "ln-hammer-imitation-k2-seed1-t0.json" and read_summary(path)["loss"][1]["step"] == 4.0
    actor = ImitationActor(summary["checkpoint"])
    targets = actor(np.zeros(60), np.zeros(52))
    assert targets.shape == (30,) and np.all(np.isfinite(targets))
    with pytest.raises(FileNotFoundError, match="no trained policy"):
        ImitationActor(tmp_path / "nowhere")
    with pytest.raises(ValueError, match="learns from the dataset.s episodes: the sweep needs a dataset_root"):
        run_imitation_point(point, dataclasses.replace(setup, dataset_root=None))


@pytest.mark.sim
@pytest.mark.train
@pytest.mark.integration
@pytest.mark.slow
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


@pytest.mark.sim
@pytest.mark.train
def test_joint_bc_clones_the_replayed_demonstrations_then_trains_in_the_joint_env(dataset: Path, tmp_path: Path,
                                                                                 monkeypatch: pytest.MonkeyPatch
                                                                                 ) -> None:
    """The joint_bc point: its demonstrations are the episodes replayed in the joint-control env (observations
    as the recorded states, returns that add up to the measure the replay reached), its actor is cloned from them
    before A2C, and it is evaluated as joint control is. An episode of another task is named."""
    from envs.replay import episode_columns, replayed_demonstrations
    from flows.train_ln import LNPoint, LNSetup, run_point
    from prl import tracking
    from prl.config import LNConfig

    cols, _ = episode_columns(dataset)
    demos = replayed_demonstrations(dataset, "hammer", [0, 1], gamma=1.0)
    assert demos.obs.shape == (300, 60 + 52 + 1) and demos.action.shape == (300, 30)
    assert np.all(np.abs(demos.action) <= 1.0)
    # the observation before step k is the recorded row k, to the replay's accuracy (test above: 0.3)
    assert np.max(np.abs(demos.obs[:, :30] - cols["observation.state"][:300, :30])) < 0.3
    assert demos.obs[0, -1] == 0.0 and demos.obs[149, -1] == pytest.approx(149 / 150)
    assert demos.ret[0] > 0.5 and demos.ret[150] > 0.5  # each replayed swing drove its nail (cm)
    with pytest.raises(ValueError, match="episode 2 of the dataset .* is of task 'unscrew', not 'hammer'"):
        replayed_demonstrations(dataset, "hammer", [0, 2], gamma=1.0)

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    tracking.configure("prl")
    setup = LNSetup(demo_dir=tmp_path / "demos", pointnet_path=None, out_dir=tmp_path / "points",
                    eval_seeds=(10_000_000,), ln=LNConfig(timesteps=64, hidden=(32, 32), pretrain_epochs=2),
                    progress=False, dataset_root=dataset)
    summary = run_point(LNPoint("hammer", "joint_bc", 2, 0), setup)
    assert len(summary["pretrain"]) == 2 * 5  # 2 epochs of 300 transitions in minibatches of 64
    assert summary["pretrain"][-1]["action_error"] < summary["pretrain"][0]["action_error"]
    assert summary["rows"][-1]["timesteps"] == 64 and summary["eval"]["n"] == 1
    assert summary["eval"]["outcomes"][0]["plan"] == []  # joint control has no plan
