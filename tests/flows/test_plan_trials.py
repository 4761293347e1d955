"""The pipeline's plan trials give the same outcomes in worker processes as in the flow's own process."""

from __future__ import annotations

import os
from pathlib import Path

import pytest


@pytest.mark.sim
def test_trials_in_two_processes_equal_one_process(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from flows.plan_trials import run_all_trials
    from prl.config import make_config

    monkeypatch.setenv("PREFECT_HOME", str(tmp_path / "prefect"))
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    got = {}
    for workers in (1, 2):
        cfg = make_config("quick", tasks=["hammer"], eval_scenes=2, workers=workers, output_dir=tmp_path / "out")
        # a fresh code version each time: Prefect's cache of a task's result must not answer the second run
        got[workers] = run_all_trials(cfg, code_version=f"test-{workers}")
        assert "PREFECT_API_URL" not in os.environ  # the processes' API address does not outlive the trials
    assert list(got[2]["hammer"]) == ["expert", "prior", "uniform"]
    for kind, outcomes in got[1]["hammer"].items():
        other = got[2]["hammer"][kind]
        assert [(o.seed, tuple(o.plan), o.success) for o in outcomes] == \
            [(o.seed, tuple(o.plan), o.success) for o in other], kind
        assert [o.measure for o in outcomes] == pytest.approx([o.measure for o in other], abs=1e-9)
    assert [o.success for o in got[1]["hammer"]["expert"]] == [True, True]  # the hammer's expert drives both nails
