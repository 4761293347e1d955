"""Reliability: a valid plan never crashes a run, a raising attempt is recorded and skipped, and a synthesis
shard killed ten times ends byte-identical to one never killed."""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from envs.synthesis import ShardSpec, read_attempts

REPO = Path(__file__).resolve().parents[2]


def test_widened_positive_ranges_stay_positive() -> None:
    from envs.tasks.base import PRLTaskEnv

    rng = np.random.RandomState(0)
    wide = SimpleNamespace(randomization=4.0)
    draws = [PRLTaskEnv._uniform(wide, rng, 0.2, 0.45) for _ in range(2000)]
    # centre 0.325, half-width 4 * 0.125 = 0.5: the upper end is 0.825; the lower end stops at 0.2 / 4
    assert 0.05 <= min(draws) < 0.07 and 0.80 < max(draws) <= 0.825
    signed = [PRLTaskEnv._uniform(wide, rng, -0.03, 0.03) for _ in range(2000)]
    assert min(signed) < -0.11 and max(signed) > 0.11  # offsets keep their full widened range
    narrow = SimpleNamespace(randomization=0.5)
    assert all(0.2625 <= PRLTaskEnv._uniform(narrow, rng, 0.2, 0.45) <= 0.3875 for _ in range(200))


@pytest.mark.sim
def test_planning_errors_become_unreachable_failures_and_bugs_still_raise(monkeypatch: pytest.MonkeyPatch) -> None:
    import envs  # noqa: F401
    from envs import executor as ex
    from envs.episode import Episode
    from envs.tasks import make_env, task_class

    env = make_env("hammer")
    try:
        executor = ex.PlanExecutor(env)
        plan = task_class("hammer").expert_plan

        def singular(self, q):  # the transport's place pose: a degenerate geometry
            raise np.linalg.LinAlgError("Singular matrix")

        monkeypatch.setattr(Episode, "plan_place", singular)
        result = executor.run(plan, seed=3)
        assert not result.success and result.fault == "unreachable"
        assert any("transport: LinAlgError: Singular matrix" in n for n in result.notes)
        assert any("place: ValueError: no place target" in n for n in result.notes)
        assert np.all(np.isfinite(result.qpos)) and len(result.frame) == 150  # it ran the whole episode

        def bug(self, q):
            raise KeyError("a bug, not an outcome")

        monkeypatch.setattr(Episode, "plan_place", bug)
        with pytest.raises(KeyError, match="a bug"):
            executor.run(plan, seed=3)
        with pytest.raises(ValueError, match="plan"):  # bad input still raises at once
            executor.run([0, 0, 0, 0, 0, 99], seed=3)
    finally:
        env.close()


@pytest.mark.sim
def test_fuzz_every_task_at_wide_randomisation() -> None:
    """Uniformly random plans at 4x the training ranges: no exception, finite recordings, every task (3 pairs each
    here; ``python -m envs.fuzz`` runs more)."""
    import envs  # noqa: F401
    from envs.fuzz import fuzz_task
    from envs.tasks import TASK_ENV_IDS

    for task in TASK_ENV_IDS:
        report = fuzz_task(task, 3, randomization=4.0, seed=5, progress=False)
        assert report.pairs == 3
        assert report.exceptions == [] and report.nonfinite == []
        assert report.successes + sum(report.faults.values()) == 3


@pytest.mark.sim
def test_a_raising_attempt_is_recorded_and_the_shard_goes_on(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import envs  # noqa: F401
    from envs import executor as ex
    from envs.synthesis import run_shard, yield_report
    from envs.trials import run_trials

    real_run = ex.PlanExecutor.run
    calls = {"n": 0}

    def flaky(self, plan, seed=None, on_stage_end=None):
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("injected PhysX error")
        return real_run(self, plan, seed, on_stage_end)

    monkeypatch.setattr(ex.PlanExecutor, "run", flaky)
    result = run_shard(ShardSpec("hammer", 0, 2, 11, tmp_path))
    rows = read_attempts(result_dir := tmp_path / "hammer" / "shard000")
    assert result.successes == 2 and result.errors == 1 and len(result.demo_paths) == 2
    assert rows[1]["success"] is False and rows[1]["error"].startswith("RuntimeError: injected PhysX error")
    assert sum("error" in r for r in rows) == 1 and len(rows) == result.attempts >= 3
    assert yield_report(tmp_path, "hammer")["errors"] == 1.0
    assert result_dir.is_dir()

    calls["n"] = 0
    outs = run_trials("hammer", [(0, 3, 2, 0, 0, 1)] * 3, [1, 2, 3], progress=False)
    assert [bool(o.error) for o in outs] == [False, True, False]
    assert outs[1].error.startswith("RuntimeError: injected") and not outs[1].success and outs[1].fail
    assert outs[0].success and outs[2].success  # the trial after the error ran on a rebuilt env
    with pytest.raises(ValueError, match="plan 1 of the trials: .*grasp_pattern is 9"):  # bad input still raises
        run_trials("hammer", [(0, 3, 2, 0, 0, 1), (0, 3, 2, 9, 0, 1)], [1, 2], progress=False)


# The child runs one shard; with "demo" or "append" it SIGKILLs itself halfway through writing the first
# demo file or the first attempt line (a torn file / a torn line), otherwise it runs until killed or done.
_CHILD = """
import os, signal, sys
from pathlib import Path
import envs
from envs import synthesis
from envs.synthesis import ShardSpec, run_shard

def die_halfway(data, fh):
    fh.write(data[: len(data) // 2])
    fh.flush()
    os.kill(os.getpid(), signal.SIGKILL)

mode = sys.argv[2]
if mode == "demo":
    import io
    import numpy as np
    real = np.savez_compressed
    def torn_savez(fh, **arrays):
        buf = io.BytesIO()
        real(buf, **arrays)
        die_halfway(buf.getvalue(), fh)
    np.savez_compressed = torn_savez
elif mode == "append":
    import json
    def torn_append(shard_dir, row):
        with open(Path(shard_dir) / "attempts.jsonl", "a") as fh:
            die_halfway(json.dumps(row) + "\\n", fh)
    synthesis._append = torn_append
from prl.proposal import ProposalConfig
synthesis.synthesize_rounds([ShardSpec("hammer", 0, 12, 23, Path(sys.argv[1]))], ProposalConfig(round_attempts=3),
                            lambda todo: [run_shard(s) for s in todo])
"""


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.mark.sim
@pytest.mark.slow
def test_ten_kills_end_byte_identical(tmp_path: Path) -> None:
    """SIGKILL a shard ten times (once inside a demo write, once inside an attempt-line append, eight times at a
    random moment after it made progress), resume after each kill: the files equal an uninterrupted run's."""
    clean, killed = tmp_path / "clean", tmp_path / "killed"
    subprocess.run([sys.executable, "-c", _CHILD, str(clean), "run"], cwd=REPO, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=600)
    want = _files(clean)
    assert sum(name.endswith(".npz") for name in want) == 12
    shard = killed / "hammer" / "shard000"
    rng = random.Random(2026)
    modes = ["run"] * 8
    modes.insert(2, "demo")
    modes.insert(6, "append")
    kills = 0
    for mode in modes:
        before = len(read_attempts(shard))
        proc = subprocess.Popen([sys.executable, "-c", _CHILD, str(killed), mode], cwd=REPO,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        if mode == "run":  # wait for one more finished attempt, then kill at a random moment of the next
            deadline = time.time() + 300
            while proc.poll() is None and len(read_attempts(shard)) <= before and time.time() < deadline:
                time.sleep(0.05)
            time.sleep(rng.uniform(0.0, 0.8))
            proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=300)
        kills += proc.returncode == -signal.SIGKILL
        if mode == "demo":
            assert list(shard.glob(".ep*.npz.tmp")), "the demo write was not cut"
        if mode == "append":
            assert not (shard / "attempts.jsonl").read_text().endswith("\n"), "the attempt line was not cut"
    assert kills >= 9  # the last random kill may come after the shard already finished
    subprocess.run([sys.executable, "-c", _CHILD, str(killed), "run"], cwd=REPO, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=600)
    got = _files(killed)
    assert sorted(got) == sorted(want)
    for name, data in want.items():
        assert got[name] == data, f"{name} differs from the uninterrupted run"
    rows = read_attempts(shard)
    assert [r["attempt"] for r in rows] == list(range(len(rows)))
