"""The reference plans' command (``flows.ln_reference``): which committed reference it keeps, what it writes, its
errors before anything runs. No simulation but in the one ``sim`` test: the plans' outcomes are stand-ins."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from types import SimpleNamespace

import pytest

from prl.ln_reference import REFERENCE_RECORD_KEYS, read_reference

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "ln"
REFERENCE = FIXTURES / "reference-hammer.json"


def test_the_committed_reference_is_kept_only_for_todays_record(tmp_path: Path) -> None:
    from flows.ln_reference import reference_decision

    shutil.copytree(FIXTURES, tmp_path / "ln")
    record = {k: read_reference(REFERENCE)[k] for k in REFERENCE_RECORD_KEYS}
    kept, note = reference_decision(tmp_path / "ln", record)
    assert kept == read_reference(REFERENCE) and note == ("reference-hammer.json: kept (same task, settings and "
                                                          "code version)")
    kept, note = reference_decision(tmp_path / "ln", {**record, "code_version": "ffffffffffffffff"})
    assert kept is None and note == ("reference-hammer.json: computing (code_version 'd0c146fe91b77c68' -> "
                                     "'ffffffffffffffff')")
    assert reference_decision(tmp_path / "ln", {**record, "task": "sweep"}) == \
        (None, "reference-sweep.json: computing (no summary yet)")


def test_settings_hold_file_names_only(tmp_path: Path) -> None:
    from flows.evaluate_rn import PRIOR_SEED_OFFSET
    from flows.ln_reference import REFERENCE_PROCEDURE, reference_settings

    assert reference_settings(2, 50) == {"eval_seed": 2, "eval_scenes": 50, "n_frames": 750,
                                         "prior_seed": 2 + PRIOR_SEED_OFFSET, "procedure": REFERENCE_PROCEDURE}
    (tmp_path / "rn-seed0.pt").write_bytes(b"an RN")
    with_rn = reference_settings(0, 4, 750, tmp_path / "rn-seed0.pt", tmp_path / "pointnet-abc.pt", 512)
    assert (with_rn["rn"], with_rn["pointnet"], with_rn["n_points"]) == ("rn-seed0.pt", "pointnet-abc.pt", 512)
    assert len(with_rn["rn_sha256"]) == 64 and not [v for v in map(str, with_rn.values()) if v.startswith("/")]


@pytest.mark.parametrize(("args", "match"), [
    (["--tasks", "hammer,juggle"], r"unknown task\(s\) \['juggle'\] in --tasks; known: hammer, sweep"),
    (["--tasks", "hammer", "--eval-scenes", "0"], "--eval-scenes must be >= 1, got 0"),
    (["--tasks", "hammer", "--rn-path", "nowhere/rn-seed0.pt"], "--rn-path 'nowhere/rn-seed0.pt': no such RN"),
])
def test_bad_arguments_are_named_before_anything_runs(tmp_path: Path, capsys: pytest.CaptureFixture, args: list,
                                                      match: str) -> None:
    from flows.ln_reference import main

    assert main([*args, "--results-dir", str(tmp_path)]) == 2
    assert re.search(match, capsys.readouterr().err)
    assert not list(tmp_path.iterdir())


def test_the_command_writes_a_reference_and_keeps_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                     capsys: pytest.CaptureFixture) -> None:
    """The command end to end with stand-in plans (``baseline_outcomes``) and scenes (``evaluation_seeds``)."""
    from flows import ln_reference

    calls: list[tuple] = []

    def fake_baselines(task_name, seeds, n_frames, randomization, prior_seed):
        calls.append((task_name, tuple(seeds), n_frames, randomization, prior_seed))
        return {kind: [SimpleNamespace(seed=s, plan=(0, 3, 2, 0, 0, 1), success=kind == "expert" or i == 0,
                                       measure=2.5, error="") for i, s in enumerate(seeds)]
                for kind in ("prior", "expert")}

    monkeypatch.setattr(ln_reference, "baseline_outcomes", fake_baselines)
    monkeypatch.setattr(ln_reference, "evaluation_seeds", lambda seed, n: [10_000_000 + 1_000 * seed + i
                                                                           for i in range(n)])
    args = ["--tasks", "hammer,sweep", "--eval-scenes", "3", "--results-dir", str(tmp_path)]
    assert ln_reference.main(args) == 0
    assert [c[0] for c in calls] == ["hammer", "sweep"] and calls[0][1:] == ((10_000_000, 10_000_001, 10_000_002),
                                                                             750, 1.0, 31)
    ref = read_reference(tmp_path / "reference-hammer.json")
    assert sorted(ref["plans"]) == ["expert", "prior"] and ref["plans"]["prior"]["successes"] == 1
    assert ref["settings"]["eval_scenes"] == 3 and "rn" not in ref["settings"]
    assert "reference-sweep.json: computing (no summary yet)" in capsys.readouterr().out
    first = (tmp_path / "reference-hammer.json").read_bytes()
    assert ln_reference.main(args) == 0 and len(calls) == 2  # kept: nothing runs again
    assert "reference-hammer.json: kept (same task, settings and code version)" in capsys.readouterr().out
    assert (tmp_path / "reference-hammer.json").read_bytes() == first
    assert ln_reference.main([*args[:3], "4", *args[4:]]) == 0 and len(calls) == 4  # other settings: again
    assert "settings differ: eval_scenes 3 -> 4" in capsys.readouterr().out
    assert json.loads((tmp_path / "reference-sweep.json").read_text())["plans"]["expert"]["n"] == 4


@pytest.mark.sim
def test_the_command_executes_the_reference_plans(tmp_path: Path) -> None:
    """Two evaluation scenes of the hammer, expert and prior plans, in simulation."""
    from envs.trials import eval_scene_seeds
    from flows.ln_reference import main

    assert main(["--tasks", "hammer", "--eval-scenes", "2", "--results-dir", str(tmp_path)]) == 0
    ref = read_reference(tmp_path / "reference-hammer.json")
    assert [o["seed"] for o in ref["plans"]["prior"]["outcomes"]] == eval_scene_seeds(0, 2)
    assert ref["plans"]["expert"]["n"] == 2 and not any(o["error"] for o in ref["plans"]["expert"]["outcomes"])


def test_extend_runs_only_the_best_fixed_plan_and_keeps_the_rn_rows(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                    capsys: pytest.CaptureFixture) -> None:
    """``--extend`` on a current reference: only the best fixed plan runs (stand-in outcomes), the RN's rows and
    settings stay though no RN is given; a reference of another code version is an error naming both."""
    from flows import ln_reference

    ref = read_reference(REFERENCE)
    record = {k: ref[k] for k in REFERENCE_RECORD_KEYS}
    plan = [1, 3, 1, 3, 4, 0]
    without_rn = {k: v for k, v in record["settings"].items() if k not in ln_reference.RN_SETTINGS}
    assert ln_reference.extendable(ref, {**record, "settings": {**without_rn, "best_fixed": plan}}) is None
    assert ln_reference.extendable(None, record) == "there is no committed reference to extend"
    assert "eval_scenes" in ln_reference.extendable(ref, {**record, "settings": {**without_rn, "eval_scenes": 5}})
    ran: list[tuple] = []

    def fake_best(task_name, settings, seeds):
        ran.append((task_name, tuple(settings["best_fixed"]), tuple(seeds)))
        return [SimpleNamespace(seed=s, plan=tuple(settings["best_fixed"]), success=i < 3, measure=1.0, error="")
                for i, s in enumerate(seeds)]

    monkeypatch.setattr(ln_reference, "best_fixed_outcomes", fake_best)
    seeds = ref["plans"]["expert"]["outcomes"]
    out = ln_reference.extend_reference(ref, {**record, "settings": {**without_rn, "best_fixed": plan}},
                                        [o["seed"] for o in seeds])
    assert ran == [("hammer", tuple(plan), tuple(o["seed"] for o in seeds))]
    assert out["plans"]["best_fixed"]["successes"] == 3 and out["plans"]["rn"] == ref["plans"]["rn"]
    assert out["settings"] == {**ref["settings"], "best_fixed": plan}
    path = ln_reference.write_reference(tmp_path, out)
    assert read_reference(path)["plans"]["best_fixed"]["outcomes"][0]["plan"] == plan
    # the fixture's code version is not today's: extending it is refused, and nothing is written
    shutil.copytree(FIXTURES, tmp_path / "ln")
    before = (tmp_path / "ln" / REFERENCE.name).read_bytes()
    monkeypatch.setattr(ln_reference, "evaluation_seeds", lambda seed, n: [o["seed"] for o in seeds])
    assert ln_reference.main(["--tasks", "hammer", "--eval-scenes", "4", "--results-dir", str(tmp_path / "ln"),
                              "--extend"]) == 2
    assert re.search(r"--extend hammer: its code version d0c146fe91b77c68 is not today's [0-9a-f]{16}",
                     capsys.readouterr().err)
    assert (tmp_path / "ln" / REFERENCE.name).read_bytes() == before and len(ran) == 1
