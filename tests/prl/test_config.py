"""Bad configuration fails before any work, naming the bad value."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
from pathlib import Path

import pytest

from prl.cli import config_overrides
from prl.config import (
    AblationConfig,
    ConfigError,
    LNConfig,
    PipelineConfig,
    make_ablation_config,
    make_config,
)
from prl.imitation import ImitationConfig


def test_quick_and_paper_profiles() -> None:
    assert make_config().eval_scenes == 8
    cfg = make_config("paper", seed=3)
    assert (cfg.eval_scenes, cfg.seed, cfg.tasks) == (50, 3, ("hammer", "sweep", "unscrew", "tweeze"))  # every task
    # dataset video: in the quick profile, 128 x 128 at 10 pictures/s; out of the paper's unless asked for
    assert make_config().video and make_config().video_spec().hold == 5 and not cfg.video
    assert make_config("paper", video=True, video_fps=25).video_spec().hold == 2


@pytest.mark.parametrize(("overrides", "match"), [
    ({"tasks": ("hamer",)}, "unknown task 'hamer'"),
    ({"tasks": ()}, "tasks is empty"),
    ({"eval_scenes": 0}, "eval_scenes must be a positive integer, got 0"),
    ({"episode_frames": -5}, "episode_frames must be a positive integer, got -5"),
    ({"seed": -1}, "seed must be a non-negative integer, got -1"),
    ({"rn_epochs": 0}, "rn_epochs must be a positive integer, got 0"),
    ({"rn_val_fraction": 1.0}, r"rn_val_fraction must be a number in \(0, 1\), got 1.0"),
    ({"wide_randomization": 0.5}, "wide_randomization must be a number >= 1, got 0.5"),
    ({"demos_per_task": 1, "tasks": ("hammer",)}, "the RN needs at least 3 demos"),
    ({"video_fps": 3}, r"video_fps must divide the dataset's 50 fps \(one of \[1, 2, 5, 10, 25, 50\]\), got 3"),
    ({"video_width": 100.5}, "video_width must be an even number of pixels in 16..4096, got 100.5"),
    ({"video": "yes"}, "video must be true or false, got 'yes'"),
    ({"rn_weighted": 1}, "rn_weighted must be true or false, got 1"),
])
def test_bad_values_are_named(overrides: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        make_config(**overrides)


def test_rn_stages_can_be_skipped_for_tiny_runs() -> None:
    assert make_config(demos_per_task=1, train_rn=False).demos_per_task == 1
    assert (make_config().rn_epochs, make_config("paper").rn_epochs) == (30, 200)


def test_unknown_profile() -> None:
    with pytest.raises(ConfigError, match="unknown profile 'huge'"):
        make_config("huge")


def test_the_tasks_of_envs_tasks_are_known_without_the_simulator(tmp_path: Path) -> None:
    """A task is a class of an ``envs/tasks`` module that sets ``task_name`` (``prl.task_registry.repo_task_names``,
    read as text, without the simulator); any other name is an error naming it and the known tasks."""
    import subprocess
    import sys

    from prl.task_registry import known_tasks, repo_task_names

    assert "unscrew_mixed" in known_tasks() and known_tasks()[:4] == ("hammer", "sweep", "unscrew", "tweeze")
    assert make_config(tasks=["unscrew_mixed", "hammer"]).tasks == ("unscrew_mixed", "hammer")
    assert make_config().tasks == ("hammer", "sweep", "unscrew", "tweeze")  # the default stays the paper's four
    assert make_ablation_config("data", "pn.pt", tasks=["unscrew_mixed"]).tasks == ("unscrew_mixed",)
    with pytest.raises(ConfigError, match=r"unknown task 'unscrew_twisted'; known tasks: hammer, sweep, unscrew, "
                                          r"tweeze, .*unscrew_mixed"):
        make_config(tasks=["unscrew", "unscrew_twisted"])
    with pytest.raises(ConfigError, match="unknown task 'mixed' in tasks"):
        make_ablation_config("data", "pn.pt", tasks=["mixed"])
    # a task is a class that names itself, whatever its file is called; a probe (pipeline_task = False) is none
    (tmp_path / "a.py").write_text('class A(PRLTaskEnv):\n    task_name = "push"\n')
    (tmp_path / "b.py").write_text('class B(A):\n    task_name = "push_far"\n\nclass C:\n    other = "x"\n')
    (tmp_path / "probe.py").write_text('class P:\n    task_name = "probe"\n    pipeline_task = False\n')
    (tmp_path / "hammer.py").write_text('class H:\n    task_name = "hammer"\n')
    assert repo_task_names(tmp_path) == ("hammer", "push", "push_far")
    # checking a config's tasks loads no simulator
    code = ("import sys; from prl.config import make_config; make_config(tasks=['unscrew_mixed']); "
            "print(sorted(m for m in ('sapien', 'mani_skill', 'torch', 'envs') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_unwritable_output_dir(tmp_path: Path) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    with pytest.raises(ConfigError, match="a_file/out.*is not writable"):
        make_config(output_dir=blocker / "out")
    assert blocker.read_text() == "x"


def test_plan_set_kinds_and_errors() -> None:
    import envs  # noqa: F401
    from envs.trials import plan_set

    assert plan_set("hammer", "expert", 2, 0) == [(0, 3, 2, 0, 0, 1)] * 2
    prior = plan_set("hammer", "prior", 20, 5)
    assert prior == plan_set("hammer", "prior", 20, 5) != plan_set("hammer", "prior", 20, 6)
    with pytest.raises(ValueError, match="unknown plan kind 'best'"):
        plan_set("hammer", "best", 1, 0)
    with pytest.raises(ValueError, match="unknown task 'nail'"):
        plan_set("nail", "expert", 1, 0)


def test_stale_hand_model_is_named(tmp_path: Path) -> None:
    from envs.hand_model import HandModelError, generate, verify_generated

    urdf, _ = generate(urdf_out=tmp_path / "hand.urdf")
    assert len(verify_generated(urdf=urdf)) == 64
    urdf.write_text(urdf.read_text().replace("FFJ3", "FFJ3x", 1))
    with pytest.raises(HandModelError, match="hand.urdf' is stale"):
        verify_generated(urdf=urdf)
    urdf.unlink()
    with pytest.raises(HandModelError, match="hand.urdf' is missing"):
        verify_generated(urdf=urdf)


def test_ln_demo_steps_follow_the_demos_and_never_exceed_them() -> None:
    assert make_config("quick").ln.demo_steps == 4  # all 4 demos of a task
    assert make_config("quick", demos_per_task=3).ln.demo_steps == 3
    assert make_config("paper").ln.demo_steps == 1280 and make_config("paper").ln.timesteps == 3200
    assert make_config("paper", demos_per_task=400).ln.demo_steps == 400
    assert make_config("quick", ln={"demo_steps": 0}).ln.demo_steps == 0  # pure RL
    with pytest.raises(ConfigError, match="ln.demo_steps=5 exceeds demos_per_task=4"):
        make_config("quick", ln={"demo_steps": 5})
    with pytest.raises(ConfigError, match=r"ln.n_envs must divide ln.steps_per_update \(64\).*got 3"):
        make_config("quick", ln={"n_envs": 3})
    assert make_config("quick", ln={"demo_steps": 5}, train_ln=False).ln.demo_steps == 5  # no LN: nothing to refuse


def test_ln_settings_are_one_nested_config_over_the_papers() -> None:
    paper = LNConfig()  # the paper's settings, defined once
    assert (paper.timesteps, paper.steps_per_update, paper.learning_rate, paper.hidden, paper.demo_steps) == \
        (3200, 64, 7e-4, (256, 256), None)
    quick = make_config("quick").ln
    assert quick == dataclasses.replace(paper, timesteps=64, n_envs=2, demo_steps=4)
    merged = make_config("quick", ln={"timesteps": 128, "hidden": [32, 32]}).ln  # JSON-like, merged over the profile's
    assert (merged.timesteps, merged.hidden, merged.n_envs) == (128, (32, 32), 2)
    assert make_config("paper", ln={"learning_rate": 1e-3}).ln.timesteps == 3200
    given = make_config("quick", ln=LNConfig(timesteps=8, n_envs=4)).ln  # an LNConfig replaces them
    assert (given.timesteps, given.n_envs, given.steps_per_update, given.demo_steps) == (8, 4, 64, 4)
    with pytest.raises(ConfigError, match="unknown setting 'ln.timestep'"):
        make_config(ln={"timestep": 8})
    with pytest.raises(ConfigError, match="unknown setting 'scenes'"):
        make_config(scenes=3)
    with pytest.raises(ConfigError, match="ln.seed is set per LN point.*got 3"):
        make_config(ln={"seed": 3})
    with pytest.raises(ConfigError, match="ln.timesteps must be a positive integer, got 0"):
        make_config(ln={"timesteps": 0})
    cfg = make_config("quick", tasks=["hammer"], output_dir="out")  # as a Prefect flow's JSON overrides give them
    assert cfg.tasks == ("hammer",) and cfg.output_dir == Path("out").resolve()


def test_ablation_config_names_bad_values(tmp_path: Path) -> None:
    cfg = make_ablation_config("data", "pn.pt", seeds=[0, 1], ln={"timesteps": 8, "steps_per_update": 4})
    assert (cfg.dataset_root, cfg.seeds, cfg.demo_steps, cfg.ln.timesteps, cfg.ln.n_envs) == \
        (Path("data"), (0, 1), (0, 1280), 8, 1)
    for overrides, match in [({"methods": ["ppo"]}, "unknown method 'ppo' in methods"),
                             ({"tasks": ["nail"]}, "unknown task 'nail' in tasks"),
                             ({"seeds": [-1]}, r"seeds must be non-negative integers .*got \(-1,\)"),
                             ({"eval_scenes": 0}, "eval_scenes must be an integer >= 1, got 0"),
                             ({"ln": {"demo_steps": 5}}, "ln.demo_steps is set per LN point.*got 5"),
                             ({"ln": {"pretrain_mode": "dagger"}}, "unknown ln.pretrain_mode 'dagger'")]:
        with pytest.raises(ConfigError, match=match):
            make_ablation_config("data", "pn.pt", **overrides)


def test_a_sweep_runs_the_papers_methods_unless_told() -> None:
    """The default sweep is the paper's three methods; the gated reward (not the paper's) only when named."""
    assert make_ablation_config("data", "pn.pt").methods == ("physics", "bc", "joint")
    assert make_ablation_config("data", "pn.pt", methods=["physics_gated"]).methods == ("physics_gated",)
    with pytest.raises(ConfigError, match="physics_gated"):
        make_ablation_config(methods=["physics_gated"])  # a plan-space method: it needs the demonstrations


def test_only_a_joint_control_sweep_runs_without_a_dataset() -> None:
    joint = make_ablation_config(methods=["joint"], seeds=[2])
    assert (joint.dataset_root, joint.pointnet_path, joint.methods) == (None, None, ("joint",))
    with pytest.raises(ConfigError, match="dataset_root is needed by the methods physics, bc"):
        make_ablation_config(methods=["joint", "physics", "bc"])
    with pytest.raises(ConfigError, match="pointnet_path is needed by the methods bc"):
        make_ablation_config("data", methods=["bc"])
    with pytest.raises(ConfigError, match="dataset_root must be a path, got 3"):
        make_ablation_config(3, "pn.pt")


def _flags(parser: argparse.ArgumentParser) -> set[str]:
    return {s for a in parser._actions for s in a.option_strings}


def _flag(name: str) -> str:
    return "--" + name.replace(".", "-").replace("_", "-")


def test_every_config_field_has_its_flag_by_its_name() -> None:
    from flows import ablation, evaluate_rn, full_pipeline

    for cls, parser, exclude in ((PipelineConfig, full_pipeline.cli_parser(), full_pipeline.CLI_EXCLUDE),
                                 (AblationConfig, ablation.cli_parser(), ablation.CLI_EXCLUDE)):
        names = [f.name for f in dataclasses.fields(cls) if f.name not in ("ln", "imitation")]
        names += [f"ln.{f.name}" for f in dataclasses.fields(LNConfig)]
        names += [f"imitation.{f.name}" for f in dataclasses.fields(ImitationConfig)] if cls is AblationConfig else []
        flags = _flags(parser)
        # the LN and imitation settings each point sets itself have none; the profile's flag is written by hand
        no_flag = {f"ln.{n}" for n in cls.LN_SET_PER_POINT}
        no_flag |= {f"imitation.{n}" for n in getattr(cls, "IMITATION_SET_PER_POINT", ())}
        assert set(exclude) - no_flag <= {"profile"}
        for name in names:
            assert (_flag(name) in flags) != (name in no_flag), (cls.__name__, name)
        assert "--no-" + _flag("reevaluate" if cls is AblationConfig else "train_rn")[2:] in flags
    assert "--draw-from" in _flags(ablation.cli_parser())
    params = inspect.signature(evaluate_rn.evaluate_rn.fn).parameters  # the flow's CLI is written by hand
    assert _flags(evaluate_rn.cli_parser()) - {"-h", "--help"} == {_flag(p) for p in params}


def test_flags_parse_into_the_config() -> None:
    from flows import ablation, full_pipeline

    args = full_pipeline.cli_parser().parse_args(
        ["--eval-scenes", "3", "--no-train-rn", "--ln-timesteps", "64", "--tasks", "hammer,sweep",
         "--ln-hidden", "32,32", "--ln-extra", '{"vf_coef": 0.25}', "--rn-val-fraction", "0.3", "--profile", "paper"])
    overrides = config_overrides(args, PipelineConfig, exclude=full_pipeline.CLI_EXCLUDE)
    assert overrides == {"tasks": ["hammer", "sweep"], "eval_scenes": 3, "train_rn": False, "rn_val_fraction": 0.3,
                         "ln": {"timesteps": 64, "hidden": [32, 32], "extra": {"vf_coef": 0.25}}}
    cfg = make_config(args.profile, **overrides)
    assert (cfg.eval_scenes, cfg.train_rn, cfg.tasks, cfg.ln.timesteps, cfg.ln.hidden, cfg.ln.extra, cfg.n_shards) == \
        (3, False, ("hammer", "sweep"), 64, (32, 32), {"vf_coef": 0.25}, 16)  # n_shards: the paper profile's
    assert config_overrides(full_pipeline.cli_parser().parse_args([]), PipelineConfig, exclude=("profile",)) == {}
    args = ablation.cli_parser().parse_args(["--dataset-root", "d", "--pointnet-path", "p.pt", "--seeds", "0,1",
                                             "--demo-steps", "0,320", "--reevaluate", "--ln-steps-per-update", "4"])
    cfg = make_ablation_config(**config_overrides(args, AblationConfig))
    assert (cfg.seeds, cfg.demo_steps, cfg.reevaluate, cfg.ln.steps_per_update) == ((0, 1), (0, 320), True, 4)


@pytest.mark.parametrize(("argv", "flag", "says"), [
    (["--eval-scenes", "three"], "--eval-scenes", "expected an integer, got 'three'"),
    (["--seeds", "0,x"], "--seeds", "expected comma-separated values: expected an integer, got 'x'"),
    (["--ln-learning-rate", "fast"], "--ln-learning-rate", "expected a number, got 'fast'"),
    (["--ln-extra", "[1]"], "--ln-extra", "expected a JSON object"),
])
def test_a_malformed_flag_is_named(argv: list[str], flag: str, says: str, capsys: pytest.CaptureFixture) -> None:
    from flows import ablation

    with pytest.raises(SystemExit):
        ablation.cli_parser().parse_args(argv)
    err = capsys.readouterr().err
    assert f"argument {flag}: {says}" in err, err
