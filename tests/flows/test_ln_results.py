"""Committed LN results on the flows' side (``flows.ln_results``, ``flows.report``, the sweep's ``--results-dir``):
what a finished point writes, which committed summaries a sweep reuses, the demonstrations' digest, the report's
command line. No simulation: fake run summaries and the fixture summaries of ``tests/fixtures/ln``."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from prl.ln_summary import RECORD_KEYS, SummaryError, read_summary

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "ln"
ONE = FIXTURES / "ln-hammer-physics-k1280-seed0-t3200.json"


def record_of(summary: dict) -> dict:
    return {k: json.loads(json.dumps(summary[k])) for k in (*RECORD_KEYS, "dataset_digest")}


def run_summary() -> dict:
    """What ``flows.train_ln.run_point`` returns, for the fixture's point."""
    rows = [{"timesteps": 64.0, "frames": 49280.0, "window_success_rate": 0.765625, "policy_loss": -0.0123456},
            {"timesteps": 128.0, "frames": 98560.0, "window_success_rate": 0.8125, "policy_loss": float("nan")}]
    outcomes = [{"seed": 10_000_000 + i, "plan": [0, 3, 2, 0, 0, 1], "success": i != 2, "measure": 1.234567,
                 "error": ""} for i in range(4)]
    return {"point": {"task": "hammer", "method": "physics", "demo_steps": 1280, "seed": 0},
            "name": "ln-hammer-physics-k1280-seed0", "run_id": "abc123", "rows": rows, "pretrain": [{"actor_loss": 1}],
            "checkpoint": "/home/someone/outputs/ablation/points/ln-hammer-physics-k1280-seed0.zip",
            "train_seconds": 1234.5678, "eval_seconds": 98.765,
            "eval": {"successes": 3, "n": 4, "ci95": [0.30064, 0.95441], "outcomes": outcomes}}


def test_a_finished_point_writes_its_committed_summary(tmp_path: Path) -> None:
    from flows.ln_results import committed_summary, point_cores
    from prl.ln_summary import write_summary

    record = record_of(read_summary(ONE))
    summary = committed_summary(run_summary(), record, "2026-12-03T10:00:00+00:00", "2026-12-03T10:25:00+00:00",
                                point_cores(1))
    path = write_summary(tmp_path, summary)
    assert path.name == "ln-hammer-physics-k1280-seed0-t3200.json"
    back = read_summary(path)
    assert {k: back[k] for k in record} == record
    assert "checkpoint" not in back and "pretrain" not in back  # no local path, no pre-training losses
    assert back["rows"][0] == {"timesteps": 64.0, "frames": 49280.0, "window_success_rate": 0.7656,
                               "policy_loss": -0.0123}
    assert back["rows"][1]["policy_loss"] is None  # NaN is not JSON
    assert back["eval"]["ci95"] == [0.3006, 0.9544] and back["eval"]["outcomes"][0]["measure"] == 1.2346
    assert (back["train_seconds"], back["eval_seconds"], back["cores"]) == (1234.6, 98.8, 1)
    assert path.read_bytes() == write_summary(tmp_path / "again", back).read_bytes()
    assert point_cores(1) == 1 and point_cores(4) == 5


def test_the_sweep_reuses_only_committed_summaries_of_todays_point(tmp_path: Path) -> None:
    from flows.ln_results import committed_summaries
    from flows.train_ln import LNPoint

    shutil.copytree(FIXTURES, tmp_path / "ln")
    points = [LNPoint("hammer", "physics", 1280, 0), LNPoint("hammer", "physics", 1280, 1),
              LNPoint("hammer", "physics", 1280, 2)]
    records = {p.name: record_of(read_summary(ONE)) for p in points}
    for p in points:
        records[p.name]["point"]["seed"] = p.seed
        records[p.name]["settings"]["ln.seed"] = p.seed
    records[points[1].name]["code_version"] = "ffffffffffffffff"  # seed 1's task code changed since
    kept, notes = committed_summaries(points, tmp_path / "ln", records)
    assert sorted(kept) == [points[0].name]  # seed 2 has no summary: run, without a note
    assert notes == [("ln-hammer-physics-k1280-seed1: re-run, ln-hammer-physics-k1280-seed1-t3200.json does not hold "
                     "today's point (code_version 'd0c146fe91b77c68' -> 'ffffffffffffffff')")]
    records[points[0].name]["timesteps"] = 640  # another budget is another file: nothing to reuse
    assert committed_summaries(points[:1], tmp_path / "ln", records) == ({}, [])
    (tmp_path / "ln" / "ln-hammer-physics-k1280-seed1-t3200.json").write_text("{")
    with pytest.raises(SummaryError, match="ln-hammer-physics-k1280-seed1-t3200.json.*not valid JSON"):
        committed_summaries(points, tmp_path / "ln", records)


def test_point_settings_name_what_decides_the_outcome(tmp_path: Path) -> None:
    from flows.ln_results import POINT_PROCEDURE, point_settings
    from flows.train_ln import LNPoint, LNSetup
    from prl.config import LNConfig
    from prl.constants import EPISODE_FRAMES

    setup = LNSetup(demo_dir=tmp_path, pointnet_path=tmp_path / "pn.pt", out_dir=tmp_path, eval_seeds=(10, 11, 12),
                    ln=LNConfig(), n_points=256)
    recipe = {"synthesis": ["seed0-shards16-frames750-adaptive-r32-s0.5-f0.2"], "episodes": 2000}
    bc = point_settings(LNPoint("hammer", "bc", 1280, 2), setup, 0, recipe)
    assert (bc["ln.pretrain_mode"], bc["ln.demo_steps"], bc["ln.seed"], bc["ln.timesteps"]) == ("bc", 1280, 2, 3200)
    assert (bc["eval_seed"], bc["eval_scenes"], bc["n_points"], bc["n_frames"], bc["procedure"]) == \
        (0, 3, 256, EPISODE_FRAMES, POINT_PROCEDURE)
    assert bc["pointnet"] == "pn.pt" and bc["dataset"] == recipe
    assert bc["sb3.vf_coef"] == 0.5 and bc["ln.learning_rate"] == 7e-4
    joint = point_settings(LNPoint("hammer", "joint", 0, 0), setup, 0)
    assert not {"pointnet", "dataset", "n_points", "n_frames"} & set(joint)  # joint control uses neither
    assert not [s for s in map(str, bc.values()) if s.startswith("/")]  # no local path
    imitation = point_settings(LNPoint("hammer", "imitation", 1280, 2), setup, 0, recipe)
    assert imitation["imitation.seed"] == 2 and imitation["imitation.steps"] == setup.imitation.steps
    assert imitation["dataset"] == recipe and not any(k.startswith(("ln.", "sb3.")) for k in imitation)
    assert not {"pointnet", "n_points", "n_frames"} & set(imitation)  # it never runs the plan environment


def test_an_imitation_summary_keeps_its_loss_and_names_a_malformed_one(tmp_path: Path) -> None:
    """An imitation point trains no RL: no curve rows, timesteps 0, its loss rows kept (rounded, thinned)."""
    from flows.ln_results import committed_summary
    from prl.ln_summary import write_summary

    record = record_of(read_summary(ONE))
    record["point"] = {"task": "hammer", "method": "imitation", "demo_steps": 1280, "seed": 0}
    record["timesteps"] = 0
    ran = {**run_summary(), "point": record["point"], "name": "ln-hammer-imitation-k1280-seed0", "rows": [],
           "loss": [{"step": 10.0, "loss": 1.23456, "l1_loss": 0.5}, {"step": 20.0, "loss": 0.654321}]}
    path = write_summary(tmp_path, committed_summary(ran, record, "2026-12-07T01:00:00+00:00",
                                                     "2026-12-07T01:30:00+00:00", 1))
    assert path.name == "ln-hammer-imitation-k1280-seed0-t0.json"
    back = read_summary(path)
    assert back["rows"] == [] and back["loss"][0] == {"step": 10.0, "loss": 1.2346, "l1_loss": 0.5}
    bad = {**back, "loss": [{"step": 10.0}]}
    path.write_text(json.dumps(bad))
    with pytest.raises(SummaryError, match="loss\\[0\\].loss"):
        read_summary(path)


def test_the_dataset_digest_is_of_the_datasets_demonstrations(tmp_path: Path) -> None:
    from flows.ln_results import task_dataset_digest
    from prl.ln_summary import demonstrations_digest

    root, demos = tmp_path / "dataset", tmp_path / "demos"
    (root / "meta").mkdir(parents=True)
    demos.mkdir()
    scenes = [{"episode_index": i, "task": t, "seed": 100 + i, "scene_params": {},
               "outcome": {"nail_descent_cm": 2.5 + i} if t == "hammer" else {"cubes_in_zone": 3},
               "source": f"/somewhere/ep{i}.npz"} for i, t in enumerate(["hammer", "sweep", "hammer"])]
    (root / "meta" / "prl_scenes.jsonl").write_text("".join(json.dumps(s) + "\n" for s in scenes))
    plan = np.array([[0, 3, 2, 0, 0, 1], [1, 3, 2, 0, 0, 1]])
    reward = np.array([2.5, 4.5], np.float32)
    np.savez(demos / "demos-hammer.npz", x=np.zeros((2, 4), np.float32), plan=plan, reward=reward,
             weight=np.ones(2, np.float32))
    digest = task_dataset_digest(root, demos, "hammer")
    assert digest == demonstrations_digest("hammer", [100, 102], plan, reward, {"weight": np.ones(2)})
    np.savez(demos / "demos-hammer.npz", x=np.ones((2, 4), np.float32), plan=plan, reward=reward,
             weight=np.ones(2, np.float32))
    assert task_dataset_digest(root, demos, "hammer") == digest  # x (the PointNet's) is a setting of its own
    np.savez(demos / "demos-hammer.npz", x=np.zeros((2, 4), np.float32), plan=plan, reward=reward[::-1])
    with pytest.raises(ValueError, match=r"demos-hammer.npz' \(2\) are not the 2 hammer episodes of the dataset"):
        task_dataset_digest(root, demos, "hammer")


def test_ablation_takes_a_results_directory(tmp_path: Path) -> None:
    from flows import ablation
    from prl.cli import config_overrides
    from prl.config import AblationConfig, ConfigError, make_ablation_config

    args = ablation.cli_parser().parse_args(["--dataset-root", "d", "--pointnet-path", "p.pt",
                                             "--results-dir", "docs/results/ln"])
    cfg = make_ablation_config(**config_overrides(args, AblationConfig))
    assert cfg.results_dir == Path("docs/results/ln")
    assert make_ablation_config("d", "p.pt").results_dir is None
    with pytest.raises(ConfigError, match="reevaluate cannot write to results_dir 'docs/results/ln'"):
        make_ablation_config("d", "p.pt", results_dir="docs/results/ln", reevaluate=True)


def test_the_report_command(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from flows.report import main

    out = ["--out", str(tmp_path / "docs" / "results.md"), "--figures-dir", str(tmp_path / "docs" / "results")]
    assert main(["--results-dir", str(tmp_path / "nowhere"), *out]) == 2
    assert "error: no LN summaries directory at" in capsys.readouterr().err
    shutil.copytree(FIXTURES, tmp_path / "ln")
    (tmp_path / "ln" / "ln-hammer-joint-k0-seed0-t3200.json").write_text("[]")
    assert main(["--results-dir", str(tmp_path / "ln"), *out]) == 2
    assert "ln-hammer-joint-k0-seed0-t3200.json" in capsys.readouterr().err
    assert main(["--results-dir", str(FIXTURES), *out]) == 0
    assert (tmp_path / "docs" / "results.md").read_text().startswith("<!-- Generated by `python -m flows.report`")


def test_the_reports_joint_frames_per_step_is_the_environments() -> None:
    from envs.joint_env import JOINT_FRAMES_PER_STEP
    from prl.report_points import JOINT_FRAMES_PER_STEP as REPORTED

    assert REPORTED == JOINT_FRAMES_PER_STEP


def test_a_sweep_with_a_results_directory_resumes_from_committed_summaries(tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """The sweep flow end to end without simulation: each point's training is a stand-in (``run_point``), run in
    this process; the dataset is its scene records and the demonstrations' file."""
    from flows import ablation, ln_results

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    monkeypatch.setenv("PREFECT_HOME", str(tmp_path / "prefect"))
    root = tmp_path / "dataset"
    (root / "meta").mkdir(parents=True)
    (root / "meta" / "prl_scenes.jsonl").write_text("".join(json.dumps(
        {"episode_index": i, "task": "hammer", "seed": 100 + i, "scene_params": {},
         "outcome": {"nail_descent_cm": 3.0}, "source": "ep.npz"}) + "\n" for i in range(3)))
    out = tmp_path / "sweep"
    (out / "demos").mkdir(parents=True)
    np.savez(out / "demos" / "demos-hammer.npz", x=np.zeros((3, 4), np.float32), plan=np.zeros((3, 6), np.int64),
             reward=np.full(3, 3.0, np.float32))
    (tmp_path / "pn.pt").write_bytes(b"a PointNet")
    ran: list[str] = []

    def fake_run_point(point, setup, parent_run_id=None):
        ran.append(point.name)
        s = run_summary()
        outcomes = [{**o, "seed": seed} for o, seed in zip(s["eval"]["outcomes"], setup.eval_seeds)]
        return {**s, "point": {"task": point.task, "method": point.method, "demo_steps": point.demo_steps,
                               "seed": point.seed}, "name": point.name,
                "eval": {"successes": sum(o["success"] for o in outcomes), "n": len(outcomes), "ci95": [0.1, 0.9],
                         "outcomes": outcomes}}

    def in_process(todo, setup, parent_id, workers, dask_address, make_task_runner, records, results_dir):
        assert results_dir is not None
        return {p.name: ln_results.ln_committed_point.fn(p, setup, parent_id, records[p.name], results_dir)
                for p in todo}

    notes: list[str] = []

    def committed(*args):
        kept, said = ln_results.committed_summaries(*args)
        notes.extend(said)
        return kept, said

    monkeypatch.setattr(ln_results, "run_point", fake_run_point)
    monkeypatch.setattr(ablation, "_fan_out", in_process)
    monkeypatch.setattr(ablation, "committed_summaries", committed)
    kwargs = {"tasks": ["hammer"], "methods": ["physics", "joint"], "demo_steps": [2], "seeds": [0],
              "eval_scenes": 3, "output_dir": str(out), "results_dir": str(tmp_path / "results")}
    first = ablation.ablation(str(root), str(tmp_path / "pn.pt"), kwargs)
    assert sorted(ran) == ["ln-hammer-joint-k0-seed0", "ln-hammer-physics-k2-seed0"]
    files = sorted(p.name for p in (tmp_path / "results").iterdir())
    assert files == ["ln-hammer-joint-k0-seed0-t3200.json", "ln-hammer-physics-k2-seed0-t3200.json"]
    physics = read_summary(tmp_path / "results" / files[1])
    assert physics["dataset_digest"] and physics["settings"]["eval_scenes"] == 3 and physics["eval"]["n"] == 3
    assert read_summary(tmp_path / "results" / files[0])["dataset_digest"] is None
    assert first["ln-hammer-physics-k2-seed0"] == physics
    (tmp_path / "mlflow.db").unlink()  # a new machine: no MLflow store, the committed summaries only
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow2.db'}")
    again = ablation.ablation(str(root), str(tmp_path / "pn.pt"), kwargs)
    assert len(ran) == 2 and again == first
    assert notes == []
    ablation.ablation(str(root), str(tmp_path / "pn.pt"), {**kwargs, "eval_scenes": 2})  # another setting
    assert len(ran) == 4 and len(notes) == 2  # re-run, and the sweep said why
    assert notes[0].startswith("ln-hammer-physics-k2-seed0: re-run") and "settings differ: eval_scenes 3 -> 2" in notes[0]
    assert read_summary(tmp_path / "results" / files[1])["eval"]["n"] == 2  # replaced
