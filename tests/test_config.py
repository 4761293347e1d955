"""Bad configuration fails before any work, naming the bad value."""

from __future__ import annotations

from pathlib import Path

import pytest

from prl.config import ConfigError, make_config


def test_quick_and_paper_profiles() -> None:
    assert make_config().eval_scenes == 8
    cfg = make_config("paper", seed=3)
    assert (cfg.eval_scenes, cfg.seed, cfg.tasks) == (50, 3, ("hammer", "sweep", "unscrew", "tweeze"))  # every task


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
    assert make_config("quick").ln_demo_steps == 4  # all 4 demos of a task
    assert make_config("quick", demos_per_task=3).ln_demo_steps == 3
    assert make_config("paper").ln_demo_steps == 1280 and make_config("paper").ln_timesteps == 3200
    assert make_config("paper", demos_per_task=400).ln_demo_steps == 400
    assert make_config("quick", ln_demo_steps=0).ln_demo_steps == 0  # pure RL
    with pytest.raises(ConfigError, match="ln_demo_steps=5 exceeds demos_per_task=4"):
        make_config("quick", ln_demo_steps=5)
    with pytest.raises(ConfigError, match="ln_envs must divide the 64 steps"):
        make_config("quick", ln_envs=3)
    assert make_config("quick", ln_demo_steps=5, train_ln=False).ln_demo_steps == 5  # no LN: nothing to refuse
