"""Scene synthesis: seeds independent of workers, yield bookkeeping, and resume after a kill."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from envs.synthesis import ShardSpec, attempt_seeds, read_attempts, resume_attempts, split_successes

REPO = Path(__file__).resolve().parents[2]


def test_split_and_seeds() -> None:
    assert split_successes(10, 4) == [3, 3, 2, 2]
    assert split_successes(2, 3) == [1, 1, 0]
    with pytest.raises(ValueError, match="n_shards must be > 0, got 0"):
        split_successes(5, 0)
    assert attempt_seeds(0, "hammer", 1, 2) == attempt_seeds(0, "hammer", 1, 2)
    seeds = {attempt_seeds(0, "hammer", k, j)[0] for k in range(4) for j in range(50)}
    assert len(seeds) == 200  # no two attempts share a scene
    assert attempt_seeds(1, "hammer", 0, 0) != attempt_seeds(0, "hammer", 0, 0)


def test_torn_attempt_line_is_dropped(tmp_path: Path) -> None:
    (tmp_path / "attempts.jsonl").write_text('{"attempt": 0, "success": false}\n{"attempt": 1, "succ')
    assert read_attempts(tmp_path) == [{"attempt": 0, "success": False}]


def test_resume_rewrites_the_log_only_to_drop_a_torn_tail(tmp_path: Path) -> None:
    log = tmp_path / "attempts.jsonl"
    log.write_text('{"attempt": 0, "success": false}\n')
    inode = log.stat().st_ino
    assert resume_attempts(tmp_path) == [{"attempt": 0, "success": False}]
    assert log.stat().st_ino == inode  # intact: left as it is
    log.write_text('{"attempt": 0, "success": false}\n{"attempt": 1, "succ')
    assert resume_attempts(tmp_path) == [{"attempt": 0, "success": False}]
    assert log.read_text() == '{"attempt": 0, "success": false}\n'
    assert resume_attempts(tmp_path / "new") == [] and not (tmp_path / "new").exists()


def test_bad_spec_values() -> None:
    with pytest.raises(ValueError, match="n_success must be >= 0, got -1"):
        ShardSpec("hammer", 0, -1, 0, Path("/tmp"))


_CHILD = """
import sys
from pathlib import Path
import envs
from envs.synthesis import ShardSpec, run_shard, synthesize_rounds
from prl.proposal import ProposalConfig
synthesize_rounds([ShardSpec("hammer", 0, 3, 11, Path(sys.argv[1]))], ProposalConfig(round_attempts=2),
                  lambda todo: [run_shard(s) for s in todo])
"""


_CHILD_SHARD = """
import sys
from pathlib import Path
import envs
from envs.synthesis import ShardSpec, run_shard
run_shard(ShardSpec("hammer", 0, 3, 11, Path(sys.argv[1])))
"""


def _rows(out: Path) -> list[dict]:
    return read_attempts(out / "hammer" / "shard000")


@pytest.mark.sim
def test_killed_shard_resumes_without_loss_or_duplicates(tmp_path: Path) -> None:
    import envs  # noqa: F401
    from envs.synthesis import run_shard
    from prl.demo import load_demo

    clean = run_shard(ShardSpec("hammer", 0, 3, 11, tmp_path / "clean"))
    assert clean.successes == 3 and len(clean.demo_paths) == 3

    out = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-c", _CHILD_SHARD, str(out)], cwd=REPO, env=dict(os.environ),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    shard = out / "hammer" / "shard000"
    while time.time() < deadline and not list(shard.glob("ep*.npz")):
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    before = sorted(p.name for p in shard.glob("ep*.npz"))
    assert 1 <= len(before) < 3, "kill should land after the first demo and before the last"
    first = {p.name: p.read_bytes() for p in shard.glob("ep*.npz")}

    resumed = run_shard(ShardSpec("hammer", 0, 3, 11, out))
    assert resumed.successes == 3
    # every finished demo survived byte for byte, none was redone or duplicated
    for name, data in first.items():
        assert (shard / name).read_bytes() == data
    assert [p.name for p in resumed.demo_paths] == [p.name for p in clean.demo_paths]
    keys = ("attempt", "seed", "plan", "success")
    assert [[r[k] for k in keys] for r in _rows(out)] == [[r[k] for k in keys] for r in _rows(tmp_path / "clean")]
    assert len({r["attempt"] for r in _rows(out)}) == len(_rows(out))
    assert load_demo(resumed.demo_paths[-1]).success
    assert not list(shard.glob(".*.tmp"))
    json.dumps(_rows(out))


def test_fast_resets_freezes_the_heap_and_always_unfreezes() -> None:
    import gc

    from envs.tasks import fast_resets

    with fast_resets():
        assert gc.get_freeze_count() > 1000  # torch, mani_skill, pytest: far more than a few objects
        frozen = gc.get_freeze_count()
        with pytest.raises(RuntimeError, match="boom"), fast_resets():
            raise RuntimeError("boom")
        # the inner block left the outer one's freeze alone (neither unfroze the heap nor froze more); a frozen
        # object may still be freed by its refcount meanwhile, so the count can drop by a few
        assert frozen - 50 <= gc.get_freeze_count() <= frozen
    assert gc.get_freeze_count() == 0
    with pytest.raises(KeyError), fast_resets():
        raise KeyError("x")
    assert gc.get_freeze_count() == 0


def test_worker_variables_pass_a_set_api_url_on() -> None:
    from prefect.settings import PREFECT_API_URL, temporary_settings

    from flows.worker_variables import worker_variables

    with temporary_settings({PREFECT_API_URL: "http://10.1.2.3:4200/api/"}):
        assert worker_variables() == {"PREFECT_API_URL": "http://10.1.2.3:4200/api", "DASK_LOGGING__DISTRIBUTED": "warning"}


def _worker_api_url() -> str:
    from prefect.client.orchestration import get_client

    with get_client(sync_client=True) as client:
        return str(client.api_url).rstrip("/")


def _worker_callbacks() -> dict[str, float]:
    """This Dask worker's periodic callbacks and their intervals in ms."""
    from distributed import get_worker

    return {name: float(pc.callback_time) for name, pc in get_worker().periodic_callbacks.items()}


@pytest.mark.sim
def test_local_dask_workers_report_to_this_process_api() -> None:
    """Without PREFECT_API_URL, the workers use this process's temporary server, not servers of their own; and
    they run without distributed's sampling profiler, whose stack trees every scene rebuild's gc.collect() would
    walk, nor does this process, where the cluster's scheduler and nannies run (``make_task_runner``); their
    periodic callbacks run at ``LOCAL_DASK_CONFIG``'s intervals, not distributed's 20 ms / 500 ms / 100 ms."""
    import threading

    import httpx
    from prefect import flow, task
    from prefect.settings import PREFECT_API_URL

    from flows.synthesize import make_task_runner

    if PREFECT_API_URL.value():
        pytest.skip(f"PREFECT_API_URL is set ({PREFECT_API_URL.value()}): no temporary server to share")
    worker_task = task(_worker_api_url, name="worker-api-url")

    callbacks_task = task(_worker_callbacks, name="worker-callbacks")

    @flow(task_runner=make_task_runner(2, None))
    def probe() -> tuple[list[str], list[dict[str, float]], list[str]]:
        return ([f.result() for f in [worker_task.submit(), worker_task.submit()]],
                [f.result() for f in [callbacks_task.submit(), callbacks_task.submit()]],
                [t.name for t in threading.enumerate()])

    urls, callbacks, threads = probe()
    assert "Profile" not in threads  # distributed.profile.watch's thread, one per profiled event loop
    here = _worker_api_url()
    assert urls == [here, here]
    for intervals in callbacks:
        assert not any(name.startswith("profile") for name in intervals)
        assert (intervals["tick"], intervals["monitor"], intervals["memory_monitor"]) == (1000.0, 10000.0, 1000.0)
    assert here.startswith("http://127.0.0.1:")
    assert httpx.get(here + "/health", timeout=10).status_code == 200


@pytest.mark.sim
def test_same_seed_gives_identical_bytes_in_two_processes(tmp_path: Path) -> None:
    """Two fresh interpreters run the same shard side by side, in rounds of the adaptive proposal: every demo
    file and the attempt log agree byte for byte (the physics, the plan sampling, the proposal's updates and the
    file format are all deterministic)."""
    outs = [tmp_path / "a", tmp_path / "b"]
    procs = [subprocess.Popen([sys.executable, "-c", _CHILD, str(out)], cwd=REPO, env=dict(os.environ),
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE) for out in outs]
    for proc in procs:
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err.decode()[-2000:]
    files = [sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file()) for out in outs]
    assert files[0] == files[1] and len(files[0]) == 4  # attempts.jsonl + 3 demos
    for rel in files[0]:
        assert (outs[0] / rel).read_bytes() == (outs[1] / rel).read_bytes(), rel


@pytest.mark.sim
def test_the_flow_on_two_dask_workers_writes_the_in_process_rounds_files_and_no_task_runs(tmp_path: Path) -> None:
    """``flows.synthesize.synthesize`` (the subflow, its shard-rounds plain Dask futures on a 2-worker local cluster)
    writes the demos and attempt logs of the same rounds run in this process, byte for byte, and creates no Prefect
    task run per shard-round (``submit_shard``: those cost the workers' throughput and a log line each)."""
    from datetime import UTC, datetime

    from prefect.client.orchestration import get_client
    from prefect.client.schemas.filters import TaskRunFilter, TaskRunFilterName, TaskRunFilterStartTime

    import envs  # noqa: F401
    from envs.synthesis import run_shard, synthesize_rounds
    from flows.synthesize import shard_specs, synthesize
    from prl.proposal import ProposalConfig

    cfg = ProposalConfig(round_attempts=2)
    shard_runs = TaskRunFilter(name=TaskRunFilterName(like_="synthesize-hammer-shard"),
                               start_time=TaskRunFilterStartTime(after_=datetime.now(UTC)))
    results = synthesize(shard_specs(["hammer"], 3, 11, 2, tmp_path / "dask"), workers=2, proposal=cfg)
    synthesize_rounds(shard_specs(["hammer"], 3, 11, 2, tmp_path / "here"), cfg,
                      lambda todo: [run_shard(s, keep_env=True) for s in todo])
    assert [(r.shard, r.successes) for r in results] == [(0, 2), (1, 1)]
    files = {name: {p.relative_to(tmp_path / name): p.read_bytes() for p in (tmp_path / name).rglob("*")
                    if p.is_file()} for name in ("dask", "here")}
    assert len(files["dask"]) == 5 and files["dask"] == files["here"]  # 2 attempt logs, 3 demos
    with get_client(sync_client=True) as client:
        assert client.read_task_runs(task_run_filter=shard_runs) == []


class _Killed(Exception):
    """Stands for a kill between two rounds."""


@pytest.mark.sim
def test_rounds_do_not_depend_on_shard_order_and_resume_after_a_kill_between_rounds(tmp_path: Path) -> None:
    """Two shards in rounds of 2 attempts with the adaptive proposal: running each round's shards in reverse
    order (as Dask workers may) and stopping after the second round then resuming both give the files of a plain
    run, byte for byte; the proposal moved after round 0 and every attempt logs its round and log-probabilities.
    The rounds replay earlier successes chosen by their importance weights (the weighted proposal; the plain one's
    bytes are the two-process test's)."""
    import envs  # noqa: F401
    from envs.synthesis import run_shard, synthesize_rounds
    from prl.proposal import ProposalConfig

    cfg = ProposalConfig(round_attempts=2, replay=0.5, weighted=True)

    def specs(out: Path) -> list[ShardSpec]:
        return [ShardSpec("hammer", k, 4, 5, out) for k in range(2)]

    seen: list[tuple[int, tuple]] = []

    def forward(todo: list[ShardSpec]) -> list:
        seen.append((todo[0].round, todo[0].proposal))
        return [run_shard(s, keep_env=True) for s in todo]

    def backward(todo: list[ShardSpec]) -> list:
        return [run_shard(s, keep_env=True) for s in reversed(todo)][::-1]

    rounds_run = []

    def dies_after_round_1(todo: list[ShardSpec]) -> list:
        if todo[0].round == 2:
            raise _Killed
        rounds_run.append(todo[0].round)
        return forward(todo)

    synthesize_rounds(specs(tmp_path / "clean"), cfg, forward)
    want = {str(p.relative_to(tmp_path / "clean")): p.read_bytes() for p in (tmp_path / "clean").rglob("*") if p.is_file()}
    assert len(seen) >= 2 and seen[1][1] != seen[0][1]  # the proposal of round 1 is not round 0's
    synthesize_rounds(specs(tmp_path / "reversed"), cfg, backward)
    with pytest.raises(_Killed):
        synthesize_rounds(specs(tmp_path / "killed"), cfg, dies_after_round_1)
    assert rounds_run == [0, 1]
    synthesize_rounds(specs(tmp_path / "killed"), cfg, forward)
    for name in ("reversed", "killed"):
        got = {str(p.relative_to(tmp_path / name)): p.read_bytes() for p in (tmp_path / name).rglob("*") if p.is_file()}
        assert sorted(got) == sorted(want)
        assert all(got[k] == v for k, v in want.items()), name
    rows = read_attempts(tmp_path / "clean" / "hammer" / "shard000")
    assert [r["round"] for r in rows] == [r["attempt"] // 2 for r in rows]
    assert all(r["prior_logp"] < 0 and r["proposal_logp"] < 0 for r in rows)
    assert rows[0]["prior_logp"] == rows[0]["proposal_logp"]  # round 0 draws from the prior


def test_a_round_replays_the_earlier_rounds_successes_of_every_shard(tmp_path: Path) -> None:
    """Rounds of 2 attempts: shard 0 kept plans A (attempt 0, round 0) and B (attempt 2, round 1), shard 1 kept C
    (attempt 1, round 0). Round 1's specs replay A and C, in shard order, and not B (a round-1 success); with a
    replay share of 0 they replay nothing."""
    from envs.synthesis import round_specs
    from prl.proposal import ProposalConfig

    plan_a, plan_b, plan_c, other = [0, 3, 2, 0, 0, 1], [1, 3, 2, 0, 0, 1], [0, 1, 2, 0, 0, 1], [0, 0, 0, 0, 0, 0]
    logs = {0: [(plan_a, True), (other, False), (plan_b, True)], 1: [(other, False), (plan_c, True)]}
    logps = {(0, 0): (-2.0, -3.0), (1, 1): (-4.0, -3.0)}  # (prior, proposal) of A and C: weights e and 1 / e
    specs = [ShardSpec("hammer", k, 5, 0, tmp_path) for k in logs]
    for spec in specs:
        spec.dir.mkdir(parents=True)
        rows = [{"attempt": j, "seed": j, "plan": plan, "round": j // 2, "success": ok, "measure": 0.0,
                 "prior_logp": logps.get((spec.shard, j), (-5.0, -5.0))[0],
                 "proposal_logp": logps.get((spec.shard, j), (-5.0, -5.0))[1]}
                for j, (plan, ok) in enumerate(logs[spec.shard])]
        (spec.dir / "attempts.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    r, todo = round_specs(specs, ProposalConfig(round_attempts=2, replay=0.5))
    assert r == 1 and [s.shard for s in todo] == [1, 0]  # shard 1 has two attempts of the round left, shard 0 one
    assert all(s.replays == (tuple(plan_a), tuple(plan_c)) and s.replay == 0.5 for s in todo)
    assert all(s.replay_weights == () for s in todo)  # unweighted: chosen uniformly
    _, todo = round_specs(specs, ProposalConfig(round_attempts=2))
    assert all(s.replays == () and s.replay == 0.0 for s in todo)
    # weighted: A and C are chosen in proportion to their importance weights, e : 1 / e (mean 1)
    _, todo = round_specs(specs, ProposalConfig(round_attempts=2, replay=0.5, weighted=True))
    e = float(np.e)
    for s in todo:
        assert s.replays == (tuple(plan_a), tuple(plan_c))
        np.testing.assert_allclose(s.replay_weights, [2 * e / (e + 1 / e), 2 / e / (e + 1 / e)])


def test_the_progress_tally_reads_only_new_complete_lines(tmp_path: Path) -> None:
    from flows.synthesize import _LogTally

    specs = [ShardSpec("hammer", k, 1, 0, tmp_path) for k in range(2)]
    tally = _LogTally(specs)
    assert tally.update() == (0, 0)
    specs[0].dir.mkdir(parents=True)
    log = specs[0].dir / "attempts.jsonl"
    log.write_text('{"attempt": 0, "success": false}\n{"attempt": 1, "success": true}\n{"attempt": 2, "su')
    assert tally.update() == (2, 1)  # the torn line is not counted yet
    with open(log, "a") as fh:
        fh.write('ccess": true}\n')
    assert tally.update() == (3, 2)
    specs[1].dir.mkdir(parents=True)
    (specs[1].dir / "attempts.jsonl").write_text('{"attempt": 0, "success": true}\n')
    assert tally.update() == (4, 3)
    log.write_text('{"attempt": 0, "success": false}\n')  # rewritten shorter on resume: every log counted again
    assert tally.update() == (2, 1)


def _scripted_round(spec: ShardSpec) -> None:
    """A shard's round without physics: plans drawn from the spec's proposal (the prior when None) with the
    attempt's own seed, a success when a0 is choice 0, lines appended as ``run_shard`` appends them."""
    import numpy as np

    from prl.plb import load_plb

    spec.dir.mkdir(parents=True, exist_ok=True)
    rows = read_attempts(spec.dir)
    ok, j = sum(r["success"] for r in rows), len(rows)
    probs = spec.proposal or load_plb().prior(spec.task)
    end = min(spec.max_attempts, spec.round_end if spec.round_end is not None else spec.max_attempts)
    with open(spec.dir / "attempts.jsonl", "a") as fh:
        while ok < spec.n_success and j < end:
            rng = np.random.default_rng(attempt_seeds(spec.run_seed, spec.task, spec.shard, j)[1])
            plan = [int(rng.choice(len(p), p=np.asarray(p) / np.sum(p))) for p in probs]
            ok += plan[0] == 0
            fh.write(json.dumps({"attempt": j, "plan": plan, "round": spec.round, "success": plan[0] == 0}) + "\n")
            j += 1


def test_a_task_runs_its_rounds_while_another_tasks_round_is_still_running(tmp_path: Path) -> None:
    """Two tasks in rounds of 2 attempts: the sweep's rounds are held back (each ends only after 6 looks), so the
    hammer runs rounds 1, 2, ... while the sweep's round 0 is still running. Every round of each task has the
    proposal and the shards of the lockstep run (``synthesize_rounds``) and every attempt line is the same."""
    from envs.synthesis import rounds_by_task, shard_result, synthesize_rounds
    from prl.proposal import ProposalConfig

    cfg = ProposalConfig(round_attempts=2)

    def specs(out: Path) -> list[ShardSpec]:
        return [ShardSpec(t, k, 5, 7, out) for t in ("hammer", "sweep") for k in range(2)]

    def lockstep_run(todo: list[ShardSpec]) -> list:
        lockstep.append((todo[0].task, todo[0].round, sorted(s.shard for s in todo), todo[0].proposal))
        for s in todo:
            _scripted_round(s)
        return [shard_result(s) for s in todo]

    lockstep: list[tuple] = []
    synthesize_rounds(specs(tmp_path / "lockstep"), cfg, lockstep_run)

    started: list[tuple] = []
    held = {"sweep": 6, "hammer": 0}

    def start(todo: list[ShardSpec]) -> dict:
        started.append((todo[0].task, todo[0].round, sorted(s.shard for s in todo), todo[0].proposal))
        return {"todo": todo, "looks": held[todo[0].task]}

    def collect(handle: dict) -> list | None:
        if handle["looks"] > 0:
            handle["looks"] -= 1
            return None
        for s in handle["todo"]:
            _scripted_round(s)
        return [shard_result(s) for s in handle["todo"]]

    idles: list[int] = []
    results = rounds_by_task(specs(tmp_path / "by_task"), cfg, start, collect, lambda: idles.append(1))
    assert sum(r.successes for r in results) == 20
    order = [(task, r) for task, r, _, _ in started]
    assert order.index(("hammer", 2)) < order.index(("sweep", 1))  # the hammer did not wait for the sweep
    for task in ("hammer", "sweep"):
        assert [e for e in started if e[0] == task] == [e for e in lockstep if e[0] == task]
    assert max(r for _, r in order) >= 2 and idles  # several rounds, and looks that found nothing ended
    for path in (tmp_path / "lockstep").rglob("attempts.jsonl"):
        assert path.read_bytes() == (tmp_path / "by_task" / path.relative_to(tmp_path / "lockstep")).read_bytes()


def test_shards_expected_to_run_longest_are_started_first(tmp_path: Path) -> None:
    """``expected_attempts`` by hand: a shard missing 3 demos at a yield of 0.5 is expected to make 6 attempts,
    capped by the 4 left in its round; one missing 1 demo, 2 attempts; one with its demos kept, 0."""
    from envs.synthesis import expected_attempts, longest_first

    spec = ShardSpec("hammer", 0, 5, 0, tmp_path, round_end=8)
    assert expected_attempts(spec, 4, 2, 0.5) == 4.0  # min(8 - 4, 3 / 0.5)
    assert expected_attempts(spec, 4, 4, 0.5) == 2.0
    assert expected_attempts(spec, 4, 5, 0.5) == 0.0
    assert expected_attempts(ShardSpec("hammer", 0, 5, 0, tmp_path), 0, 0, 0.0) == 10_000  # no yield yet: capped
    specs = [ShardSpec("hammer", k, 5, 0, tmp_path, round_end=8) for k in range(3)]
    # the task's yield so far: 7 successes of 14 attempts = 0.5
    logs = {("hammer", 0): [{"success": True}] * 4 + [{"success": False}] * 4,  # 1 missing, no attempt left: 0
            ("hammer", 1): [{"success": True}] * 2 + [{"success": False}] * 2,  # 3 missing: min(4, 6) = 4
            ("hammer", 2): [{"success": True}, {"success": False}]}  # 4 missing: min(6, 8) = 6
    assert [s.shard for s in longest_first(specs, logs)] == [2, 1, 0]
