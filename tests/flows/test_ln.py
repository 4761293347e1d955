"""The Learning Network: paper settings, demonstration pre-training, save/load, the ablation sweep (its plan and
joint-control environments are tested in ``tests/envs/test_plan_env.py``)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from prl.ln import Demonstrations, LNConfig, load_ln, make_ln, predict_plans, pretrain, save_ln

REPO = Path(__file__).resolve().parents[2]


class Bandit(gym.Env):
    """A contextual bandit: x ~ N(0, 1)^8; the expert action is (2, 1) when x[0] > 0, else (0, 3); reward 1 for it."""

    def __init__(self) -> None:
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (8,), np.float32)
        self.action_space = gym.spaces.MultiDiscrete([3, 4])
        self.rng = np.random.default_rng(0)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = self.rng.normal(size=8).astype(np.float32)
        return self.x, {}

    def step(self, action):
        ok = bool(np.array_equal(np.asarray(action), expert(self.x[None])[0]))
        return self.x, float(ok), True, False, {"success": ok, "measure": float(ok)}


def expert(x: np.ndarray) -> np.ndarray:
    return np.where(x[:, :1] > 0, [[2, 1]], [[0, 3]]).astype(np.int64)


def bandit_demos(n: int = 256, seed: int = 1) -> Demonstrations:
    x = np.random.default_rng(seed).normal(size=(n, 8)).astype(np.float32)
    return Demonstrations(x, expert(x), np.ones(n, np.float32))


def bandit_model(cfg: LNConfig | None = None):
    return make_ln(Bandit(), cfg or LNConfig(), np.zeros(8), np.ones(8))


def expert_prob_and_value(model, x: np.ndarray) -> tuple[float, float]:
    obs = torch.as_tensor(x)
    with torch.no_grad():
        values, log_prob, _ = model.policy.evaluate_actions(obs, torch.as_tensor(expert(x)))
    return float(log_prob.exp().mean()), float(values.mean())


def test_a2c_settings_are_the_papers() -> None:
    paper = {"learning_rate": 7e-4, "steps_per_update": 64, "gamma": 0.99, "gae_lambda": 0.95,
             "ent_coef": 0.01, "hidden": (256, 256), "timesteps": 3200}
    cfg = LNConfig()  # the paper's settings are its defaults
    assert {k: getattr(cfg, k) for k in paper} == paper
    model = bandit_model()
    assert (model.learning_rate, model.n_steps * model.n_envs, model.gamma, model.gae_lambda, model.ent_coef) == \
        (7e-4, 64, 0.99, 0.95, 0.01)
    widths = [m.out_features for m in model.policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
    assert widths == [256, 256]
    assert [m.out_features for m in model.policy.mlp_extractor.value_net if isinstance(m, torch.nn.Linear)] == [256, 256]
    assert LNConfig(n_envs=2).n_steps == 32
    params = cfg.params()  # SB3's defaults that the paper leaves open are recorded too
    assert params["sb3.vf_coef"] == 0.5 and params["sb3.max_grad_norm"] == 0.5 and params["ln.timesteps"] == 3200


def test_pretraining_minibatch_is_one_a2c_update_and_points_derive_their_settings() -> None:
    import dataclasses

    from flows.train_ln import LNPoint, point_config

    assert len(pretrain(bandit_model(), bandit_demos(256), epochs=1)) == 256 // 64  # the paper's 64 per update
    assert len(pretrain(bandit_model(LNConfig(steps_per_update=32)), bandit_demos(256), epochs=1)) == 256 // 32
    run = LNConfig(timesteps=64, n_envs=2, learning_rate=1e-3)
    assert point_config(LNPoint("hammer", "bc", 320, 2), run) == \
        dataclasses.replace(run, demo_steps=320, pretrain_mode="bc", seed=2)
    assert point_config(LNPoint("hammer", "physics", 0, 1), run).pretrain_mode == "actor_critic"


def test_the_gated_method_pays_the_measure_only_on_success() -> None:
    """``physics_gated``: the measure where the episode met the success rule, else 0, computed by hand; through the
    SB3 wrapper the A2C reads rewards from; and otherwise the physics method's settings."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from flows.train_ln import LNPoint, gated_rewards, point_config, success_gated

    infos = [{"success": True, "measure": 114.0}, {"success": False, "measure": 163.0}, {"measure": 9.0}]
    assert gated_rewards(np.array([114.0, 163.0, 9.0], np.float32), infos).tolist() == [114.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="3 rewards but 2 infos"):
        gated_rewards(np.zeros(3), infos[:2])

    class Spin(gym.Env):  # pays 5 for every action; succeeds only on action 1
        observation_space = gym.spaces.Box(-1, 1, (2,), np.float32)
        action_space = gym.spaces.Discrete(2)

        def reset(self, *, seed=None, options=None):
            return np.zeros(2, np.float32), {}

        def step(self, action):
            return np.zeros(2, np.float32), 5.0, True, False, {"success": int(action) == 1}

    venv = success_gated(DummyVecEnv([Spin, Spin]))
    venv.reset()
    _, rewards, dones, infos = venv.step(np.array([0, 1]))
    assert rewards.tolist() == [0.0, 5.0] and dones.all() and [i["success"] for i in infos] == [False, True]
    run = LNConfig(timesteps=64)
    assert point_config(LNPoint("unscrew_mixed", "physics_gated", 1280, 1), run) == \
        point_config(LNPoint("unscrew_mixed", "physics", 1280, 1), run)
    assert LNPoint("unscrew_mixed", "physics_gated", 1280, 1).name == "ln-unscrew_mixed-physics_gated-k1280-seed1"


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"n_envs": 3}, r"ln.n_envs must divide ln.steps_per_update \(64\)"),
    ({"pretrain_mode": "dagger"}, "unknown ln.pretrain_mode 'dagger'"),
    ({"timesteps": -1}, "timesteps"), ({"learning_rate": float("nan")}, "learning_rate"), ({"hidden": (256, 0)}, "hidden"),
])
def test_bad_ln_config_is_named(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        LNConfig(**kwargs)


def test_actor_critic_pretraining_raises_expert_probability_and_critic_estimate() -> None:
    model = bandit_model()
    x_test = np.random.default_rng(9).normal(size=(128, 8)).astype(np.float32)
    p0, v0 = expert_prob_and_value(model, x_test)
    assert p0 < 0.2  # 1 of 12 joint actions at initialisation
    rows = pretrain(model, bandit_demos(), "actor_critic", epochs=15, seed=0)
    p1, v1 = expert_prob_and_value(model, x_test)
    assert p1 > 0.8 and p1 > p0 + 0.5
    assert abs(v1 - 1.0) < 0.25 and abs(v0) < 0.3  # the critic learned the demonstrations' reward (1)
    assert rows[-1]["actor_loss"] < rows[0]["actor_loss"] and rows[-1]["critic_loss"] < rows[0]["critic_loss"]
    assert np.mean(predict_plans(model.policy, x_test) == expert(x_test)) > 0.9


def test_bc_trains_the_actor_and_leaves_the_critic_as_it_was() -> None:
    model = bandit_model()
    x_test = np.random.default_rng(9).normal(size=(128, 8)).astype(np.float32)
    _, v0 = expert_prob_and_value(model, x_test)
    pretrain(model, bandit_demos(), "bc", epochs=15, seed=0)
    p1, v1 = expert_prob_and_value(model, x_test)
    assert p1 > 0.8 and v1 == pytest.approx(v0, abs=1e-6)


def test_rl_after_pretraining_keeps_solving_the_bandit() -> None:
    from prl.ln import train_ln

    model = bandit_model(LNConfig(timesteps=128))
    pretrain(model, bandit_demos(), "actor_critic", epochs=15, seed=0)
    rows = train_ln(model, 128, progress=False)
    assert [r["timesteps"] for r in rows] == [64.0, 128.0]
    assert all(r["episodes"] == 64 for r in rows) and rows[-1]["success_rate"] > 0.7
    assert {"policy_loss", "value_loss", "entropy"} <= rows[0].keys()


def test_demo_steps_beyond_the_demonstrations_are_refused() -> None:
    demos = bandit_demos(10)
    assert len(demos.take(10, seed=0).x) == 10 and len(demos.take(0, seed=0).x) == 0
    with pytest.raises(ValueError, match="demo_steps=11 exceeds the 10 demonstration transitions"):
        demos.take(11, seed=0)


def test_task_demonstrations_name_what_is_missing() -> None:
    from prl.ln import task_demonstrations

    x, plans = np.zeros((2, 4), np.float32), np.zeros((2, 6), np.int64)
    got = task_demonstrations("hammer", "nail_descent_cm", x, plans, ["hammer", "sweep"],
                              [{"nail_descent_cm": 1.5}, {"cubes_in_zone": 5}])
    assert got.reward.tolist() == [1.5] and len(got.x) == 1
    with pytest.raises(ValueError, match="no demonstration of task 'unscrew'"):
        task_demonstrations("unscrew", "turn_deg", x, plans, ["hammer", "sweep"], [{}, {}])
    with pytest.raises(ValueError, match="records no 'nail_descent_cm'"):
        task_demonstrations("hammer", "nail_descent_cm", x, plans, ["hammer", "sweep"], [{}, {}])


def test_save_and_load_give_identical_actions(tmp_path: Path) -> None:
    model = bandit_model()
    pretrain(model, bandit_demos(), "actor_critic", epochs=2, seed=0)
    x = np.random.default_rng(3).normal(size=(64, 8)).astype(np.float32)
    path = save_ln(model, tmp_path / "ln.zip")
    again = load_ln(path)
    np.testing.assert_array_equal(predict_plans(again.policy, x), predict_plans(model.policy, x))
    torch.testing.assert_close(again.policy.features_extractor.mean, model.policy.features_extractor.mean)
    with pytest.raises(FileNotFoundError, match="no LN checkpoint"):
        load_ln(tmp_path / "missing.zip")
    with pytest.raises(ValueError, match="does not end in .zip"):
        save_ln(model, tmp_path / "ln.pt")


def test_ln_points_and_sweeps_name_bad_input() -> None:
    from flows.ablation import sweep_points
    from flows.train_ln import LNPoint

    with pytest.raises(ValueError, match="unknown LN method 'ppo'"):
        LNPoint("hammer", "ppo")
    with pytest.raises(ValueError, match="joint-control baseline has no demonstration"):
        LNPoint("hammer", "joint", 1280)
    points = sweep_points(["hammer"], ["physics", "bc", "joint"], [0, 1280], [0, 1, 2])
    assert [p.name for p in points[:3]] == ["ln-hammer-physics-k0-seed0", "ln-hammer-physics-k0-seed1",
                                            "ln-hammer-physics-k0-seed2"]
    assert len(points) == 6 + 3 + 3  # physics K=0 and K=1280, bc K=1280, joint once; 3 seeds each
    with pytest.raises(ValueError, match="the imitation method learns from demonstrations alone"):
        LNPoint("hammer", "imitation", 0)
    imitation = sweep_points(["hammer"], ["imitation", "joint_bc"], [0, 1280], [0, 1])
    assert [p.name for p in imitation] == ["ln-hammer-imitation-k1280-seed0", "ln-hammer-imitation-k1280-seed1",
                                           "ln-hammer-joint_bc-k1280-seed0", "ln-hammer-joint_bc-k1280-seed1"]
    with pytest.raises(ValueError, match="the joint_bc method learns from demonstrations"):
        LNPoint("hammer", "joint_bc", 0)


def test_the_sweep_progress_counts_only_each_points_latest_run() -> None:
    from types import SimpleNamespace

    from flows.ablation import latest_point_runs

    def run(point: str, start: int, steps: float) -> SimpleNamespace:
        return SimpleNamespace(data=SimpleNamespace(tags={"ln_point": point}, metrics={"ln/timesteps": steps}),
                               info=SimpleNamespace(start_time=start))

    killed, again, other, elsewhere = run("a", 1, 768.0), run("a", 5, 64.0), run("b", 2, 128.0), run("c", 9, 1.0)
    got = latest_point_runs([killed, again, other, elsewhere], {"a", "b"})
    assert got == [again, other]  # 64 + 128 timesteps, not the killed run's 768 as well


def test_fig8_redrawn_from_sweep_directories(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    import json

    from flows.ablation import main, read_summaries

    assert main(["--draw-from", str(tmp_path / "nowhere"), "--output-dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "no LN point summaries under" in err and "nowhere" in err
    assert main(["--tasks", "hammer"]) == 2  # a sweep of plan-space methods needs --dataset-root and --pointnet-path
    assert "dataset_root is needed by the methods physics, bc" in capsys.readouterr().err
    for d, steps in (("short", 2), ("long", 3)):  # the same joint point at two budgets, in two sweeps
        rows = [{"timesteps": float(t), "frames": 10.0 * t, "window_success_rate": 0.1 * t} for t in range(1, steps + 1)]
        (tmp_path / d / "points").mkdir(parents=True)
        (tmp_path / d / "points" / "ln-hammer-joint-k0-seed0.json").write_text(json.dumps(
            {"name": "ln-hammer-joint-k0-seed0", "rows": rows,
             "point": {"task": "hammer", "method": "joint", "demo_steps": 0, "seed": 0}}))
    both = read_summaries([str(tmp_path / "short"), str(tmp_path / "long")])
    assert sorted(both) == ["ln-hammer-joint-k0-seed0@2", "ln-hammer-joint-k0-seed0@3"]
    assert main(["--draw-from", f"{tmp_path / 'short'},{tmp_path / 'long'}", "--output-dir", str(tmp_path / "fig")]) == 0
    assert (tmp_path / "fig" / "fig8_hammer_frames.png").stat().st_size > 10_000


def test_unknown_task_is_named(tmp_path: Path) -> None:
    from envs.joint_env import JointControlEnv
    from envs.plan_env import PlanEnv

    with pytest.raises(ValueError, match="unknown task 'hamer'"):
        PlanEnv("hamer", tmp_path / "pn.pt")
    with pytest.raises(ValueError, match="unknown task 'hamer'"):
        JointControlEnv("hamer")


def test_two_processes_logging_at_once_lose_nothing(tmp_path: Path) -> None:
    """Two workers (as in the ablation sweep) write child runs of one parent into one sqlite store at once."""
    import mlflow

    from prl import tracking

    env = dict(os.environ, MLFLOW_TRACKING_URI=f"sqlite:///{tmp_path / 'mlflow.db'}")
    os.environ["MLFLOW_TRACKING_URI"] = env["MLFLOW_TRACKING_URI"]
    try:
        tracking.configure("prl")
        with mlflow.start_run(run_name="parent") as parent:
            pass
        code = ("import sys, mlflow; from prl import tracking; tracking.configure('prl')\n"
                "with tracking.child_run(sys.argv[1], parent_run_id=sys.argv[2]):\n"
                "    for i in range(150):\n"
                "        mlflow.log_metrics({'ln/a': i, 'ln/b': 2 * i}, step=i)\n")
        procs = [subprocess.Popen([sys.executable, "-c", code, f"w{k}", parent.info.run_id], cwd=REPO, env=env,
                                  stderr=subprocess.PIPE, text=True) for k in range(2)]
        errors = [p.communicate(timeout=300)[1] for p in procs]
        assert [p.returncode for p in procs] == [0, 0], errors
        runs = mlflow.search_runs(filter_string=f"tags.mlflow.parentRunId = '{parent.info.run_id}'", output_format="list")
        assert sorted(r.info.run_name for r in runs) == ["w0", "w1"]
        client = mlflow.tracking.MlflowClient()
        for r in runs:
            assert r.info.status == "FINISHED"
            assert [m.step for m in client.get_metric_history(r.info.run_id, "ln/b")] == list(range(150))
    finally:
        os.environ.pop("MLFLOW_TRACKING_URI", None)


# ----------------------------------------------------------------------------- simulation tier


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A LeRobot dataset of 3 real hammer demos (episodes shortened to 300 frames)."""
    import envs  # noqa: F401
    from envs.execution import ExecutorConfig
    from envs.executor import PlanExecutor
    from envs.tasks import make_env
    from prl.demo import from_episode, save_demo
    from prl.export import export_lerobot
    from prl.plb import load_plb

    out = tmp_path_factory.mktemp("ln_demos")
    env = make_env("hammer")
    try:
        executor = PlanExecutor(env, ExecutorConfig(n_frames=300))
        paths = [save_demo(from_episode("hammer", seed, load_plb().texts("hammer")[0],
                                        executor.run([0, 3, 2, 0, 0, 1], seed=seed), env), out / f"ep{seed}.npz")
                 for seed in (3, 4, 5)]
    finally:
        env.close()
    return export_lerobot(paths, out / "dataset", repo_id="prl/hammer").root


@pytest.mark.sim
def test_ablation_sweep_runs_points_on_dask_and_resumes(tmp_path: Path, tiny_dataset: Path, pointnet_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    import mlflow

    from flows.ablation import ablation

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    monkeypatch.setenv("PREFECT_HOME", str(tmp_path / "prefect"))
    kwargs = {"tasks": ["hammer"], "methods": ["physics", "joint"], "demo_steps": [2], "seeds": [0],
              "ln": {"timesteps": 8, "steps_per_update": 4}, "eval_scenes": 1, "workers": 2, "n_points": 64,
              "output_dir": str(tmp_path / "sweep")}  # the flow's overrides, as a deployment run passes them
    with pytest.raises(ValueError, match="demo_steps=4 exceeds the 3 hammer demonstrations"):
        ablation(str(tiny_dataset), str(pointnet_path), {**kwargs, "demo_steps": [4]})
    first = ablation(str(tiny_dataset), str(pointnet_path), kwargs)
    assert sorted(first) == ["ln-hammer-joint-k0-seed0", "ln-hammer-physics-k2-seed0"]
    mlflow.set_tracking_uri(f"sqlite:///{tmp_path / 'mlflow.db'}")
    runs = mlflow.search_runs(experiment_names=["prl"], filter_string="tags.ln_point != ''", output_format="list")
    assert sorted(r.info.run_name for r in runs) == sorted(first) and {r.info.status for r in runs} == {"FINISHED"}
    parents = {r.data.tags["mlflow.parentRunId"] for r in runs}
    assert len(parents) == 1  # one sweep parent, both points under it, logged from two Dask workers
    physics = first["ln-hammer-physics-k2-seed0"]
    assert [r["timesteps"] for r in physics["rows"]] == [4.0, 8.0] and len(physics["pretrain"]) == 10
    assert physics["eval"]["n"] == 1 and first["ln-hammer-joint-k0-seed0"]["eval"]["n"] == 1
    assert (tmp_path / "sweep" / "fig8_hammer_timesteps.png").stat().st_size > 10_000
    again = ablation(str(tiny_dataset), str(pointnet_path), kwargs)  # resumed: nothing re-run
    assert again == first
    runs = mlflow.search_runs(experiment_names=["prl"], filter_string="tags.ln_point != ''", output_format="list")
    assert len(runs) == 2
    grown = ablation(str(tiny_dataset), str(pointnet_path), {**kwargs, "methods": ["physics"], "seeds": [0, 1]})
    assert sorted(grown) == ["ln-hammer-physics-k2-seed0", "ln-hammer-physics-k2-seed1"]
    assert grown["ln-hammer-physics-k2-seed0"] == first["ln-hammer-physics-k2-seed0"]  # reused, not re-run
    runs = mlflow.search_runs(experiment_names=["prl"], filter_string="tags.ln_point != ''", output_format="list")
    assert len(runs) == 3 and len({r.data.tags["mlflow.parentRunId"] for r in runs}) == 1
    again = ablation(str(tiny_dataset), str(pointnet_path), {**kwargs, "reevaluate": True})  # no retraining
    assert sorted(again) == sorted(first)
    for name, s in again.items():
        assert s["eval_before"] == first[name]["eval"] and s["eval"]["n"] == 1 and s["rows"] == first[name]["rows"]
        assert mlflow.get_run(s["run_id"]).data.tags["reevaluated_at_code"]
    assert len(mlflow.search_runs(experiment_names=["prl"], filter_string="tags.ln_point != ''",
                                  output_format="list")) == 3
    joint = ablation(None, None, {**kwargs, "methods": ["joint"], "seeds": [1], "workers": 1,
                                  "output_dir": str(tmp_path / "joint")})  # joint control alone: no dataset
    assert sorted(joint) == ["ln-hammer-joint-k0-seed1"] and joint["ln-hammer-joint-k0-seed1"]["eval"]["n"] == 1
    assert not (tmp_path / "joint" / "demos").exists()
