"""Scene synthesis: domain-randomised scenes x plans drawn from the task's proposal -> kept demos.

Work is split into a fixed number of shards. Attempt ``j`` of shard ``k`` uses a scene seed and
a plan drawn from generators seeded by ``(run seed, task, k, j)`` only, so the result does not
depend on how many workers run the shards, nor on the order they run in. A shard stops when it
has its share of successes (or ``max_attempts`` attempts).

Plans are drawn from the task's proposal (``prl.proposal``): its prior, or the adaptive proposal (mixed with the
prior, its defensive share, and with replays of earlier rounds' successful plans, its replay share), which changes
between rounds of ``round_attempts`` attempts per shard. ``rounds_by_task`` runs the rounds:
every unfinished shard runs its attempts of round r with the proposal computed from the attempt logs of
rounds < r of all the task's shards, and the task's round r + 1 starts when its round r has ended in all
its shards (other tasks' rounds need not have ended). A prior run is one round without limit (the plans
and files of a run before rounds existed, plus the two log-probabilities).

On disk, per shard ``<out>/<task>/shard<k>/``:

* ``attempts.jsonl`` - one line per finished attempt (seed, plan, its ``round``, ``proposal_logp`` and
  ``prior_logp``: the plan's log-probability under the proposal that drew it and under the task's prior,
  success, measure; ``fault`` when the
  executor ended a failed plan itself, ``decided`` with the reason and ``frames`` with the physics frames
  stepped when the attempt was ended early as a decided failure (``ExecutorConfig.end_decided``: its measure is
  then the one at the early end), ``replayed: false`` when it succeeded but its ``action`` stream replayed at
  50 Hz did not (``ShardSpec.replay_check``: no demo is kept), ``error`` with the exception text when the
  attempt raised), appended
  and flushed, so the yield per task and per plan dimension, and how often attempts fault or err, can be
  computed. An attempt that raises (a bug, a PhysX error) is recorded as failed and the shard goes on
  with a rebuilt environment;
* ``ep<j>.npz`` - one file per successful attempt (``prl.demo``), written atomically.

Resume: a shard re-reads its ``attempts.jsonl`` and continues after the last finished attempt.
A demo is saved before its attempt line; an attempt whose demo exists but whose line is
missing (killed in between) is recorded from the demo and not executed again. Nothing
finished is lost or duplicated.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from envs.execution import ExecutorConfig
from envs.executor import PlanExecutor
from envs.replay import demo_replays
from envs.tasks import fast_resets, make_env, task_class
from envs.trials import error_text
from prl.atomic import write_atomic
from prl.constants import EPISODE_FRAMES
from prl.demo import from_episode, load_demo, save_demo
from prl.plb import load_plb
from prl.proposal import (
    ProposalConfig,
    as_probs,
    log_prob,
    mixture_log_prob,
    round_proposals,
    sample_mixture,
    sample_plan,
)
from prl.stages import FAULTS
from prl.stats import importance_weights

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ShardSpec:
    """One shard of a synthesis run (picklable: paths and numbers only)."""

    task: str
    """Task name."""
    shard: int
    """Shard index."""
    n_success: int
    """Successful demonstrations this shard must keep."""
    run_seed: int
    """The run's seed; every attempt's seeds derive from it."""
    out_dir: Path
    """Root of the synthesis output (``<out_dir>/<task>/shard<k>``)."""
    max_attempts: int = 10_000
    """Give up after this many attempts (a task whose prior almost never succeeds)."""
    n_frames: int = EPISODE_FRAMES
    """Physics frames per plan episode."""
    proposal: tuple[tuple[float, ...], ...] | None = None
    """Per-dimension probabilities the plans of this call are drawn from (None: the task's prior)."""
    round: int = 0
    """The round these attempts belong to (recorded in each attempt's line)."""
    round_end: int | None = None
    """Stop before this attempt index (the end of the round; None: run until the shard is done)."""
    defensive: float | None = None
    """Draw each plan from the prior with this probability, else from ``proposal`` (the defensive mixture of
    ``prl.proposal``; None: from ``proposal`` alone)."""
    replays: tuple[tuple[int, ...], ...] = ()
    """The plans of the earlier rounds' successes of the task (all shards), which an adapted draw replays with
    probability ``replay`` (``prl.proposal.sample_mixture``)."""
    replay: float = 0.0
    """Share of the adapted draws that replay one of ``replays``."""
    replay_weights: tuple[float, ...] = ()
    """One weight per plan of ``replays`` (its importance weight: a weighted proposal) that a replay is chosen in
    proportion to; empty: uniformly."""
    replay_check: bool = False
    """Keep a successful attempt's demo only when its ``action`` stream replays it at the dataset's 50 Hz
    (``envs.replay.demo_replays``); one that does not is recorded as failed, with ``replayed: false``."""

    def __post_init__(self) -> None:
        if self.n_success < 0:
            raise ValueError(f"n_success must be >= 0, got {self.n_success!r}")
        if self.max_attempts <= 0:
            raise ValueError(f"max_attempts must be > 0, got {self.max_attempts!r}")

    def done(self, attempts: int, successes: int) -> bool:
        """Whether a shard with these counts has nothing left to do (its share kept, or out of attempts)."""
        return successes >= self.n_success or attempts >= self.max_attempts

    @property
    def call_end(self) -> int:
        """The attempt index this call stops before: the round's end, capped by ``max_attempts``."""
        return self.max_attempts if self.round_end is None else min(self.max_attempts, self.round_end)

    @property
    def dir(self) -> Path:
        return Path(self.out_dir) / self.task / f"shard{self.shard:03d}"


@dataclass(frozen=True)
class ShardResult:
    """What a shard holds after running."""

    task: str
    shard: int
    attempts: int
    successes: int
    demo_paths: tuple[Path, ...]
    errors: int = 0
    """Attempts that raised (recorded as failed, with the error text in ``attempts.jsonl``)."""
    seconds: float = 0.0
    """Wall time of this call (not written to any file: the files stay byte-identical across runs)."""


def attempt_seeds(run_seed: int, task: str, shard: int, attempt: int) -> tuple[int, int]:
    """(scene seed, plan-sampling seed) of one attempt: a hash of its coordinates."""
    digest = hashlib.sha256(f"{run_seed}/{task}/{shard}/{attempt}".encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF, int.from_bytes(digest[4:12], "little")


def split_successes(n_success: int, n_shards: int) -> list[int]:
    """Successes per shard: ``n_success`` split as evenly as possible over ``n_shards``."""
    if n_shards <= 0:
        raise ValueError(f"n_shards must be > 0, got {n_shards!r}")
    base, extra = divmod(n_success, n_shards)
    return [base + (1 if k < extra else 0) for k in range(n_shards)]


def read_attempts(shard_dir: Path) -> list[dict]:
    """The finished attempts of a shard (a torn last line from a kill is ignored)."""
    path = Path(shard_dir) / "attempts.jsonl"
    return _parse_attempts(path.read_text())[0] if path.exists() else []


def _parse_attempts(text: str) -> tuple[list[dict], str]:
    """The finished attempts of an attempt log's text, and the text of their lines alone."""
    rows, lines = [], []
    for line in text.splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            break  # a line cut by a kill: that attempt is re-run
        lines.append(line + "\n")
    return rows, "".join(lines)


def resume_attempts(shard_dir: Path) -> list[dict]:
    """:func:`read_attempts`, with the log rewritten without its torn tail when a kill left one, so that appends stay
    line-aligned. Only then, and atomically: rewriting it in place at every shard-round could be cut by a kill,
    losing the log, and showed the flow's progress tally a log shorter than it had read."""
    path = Path(shard_dir) / "attempts.jsonl"
    if not path.exists():
        return []
    text = path.read_text()
    rows, intact = _parse_attempts(text)
    if intact != text:
        write_atomic(path, intact)
    return rows


def _append(shard_dir: Path, row: dict) -> None:
    with open(Path(shard_dir) / "attempts.jsonl", "a") as fh:
        fh.write(json.dumps(row) + "\n")
        fh.flush()


_KEPT: dict[tuple[str, int], tuple[Any, PlanExecutor | None, ExitStack]] = {}
"""Environments kept alive between ``run_shard`` calls of one process (``keep_env``): a Dask worker runs many
shard-rounds of a few tasks, and rebuilding the env for each would cost more than a round's worth of resets."""


def _environment(task: str, n_frames: int, keep: bool, cleanup: ExitStack) -> tuple[Any, PlanExecutor]:
    """The task's env and executor: a kept one (``keep``), or a new one closed by ``cleanup``."""
    key = (task, int(n_frames))
    if keep and key in _KEPT:
        return _KEPT[key][:2]
    stack = ExitStack()
    env = make_env(task)
    stack.callback(env.close)
    stack.enter_context(fast_resets())
    # a failed attempt keeps nothing but its failure: it ends as soon as its task says it can no longer succeed
    # (envs.tasks.base.PRLTaskEnv.failure_decided; the same successes as full episodes on 500 attempts per task,
    # bench/bench_decided.py); kept demos, successes, always run to their end
    executor = PlanExecutor(env, ExecutorConfig(n_frames=n_frames, end_decided=True))
    if keep:
        _KEPT[key] = (env, executor, stack)
    else:
        cleanup.push(stack)
    return env, executor


def _replay_environment(task: str, steps: int, keep: bool, cleanup: ExitStack) -> Any:
    """The task's joint-control env of ``steps`` 50 Hz steps that checks a demo's replay (``replay_check``): a kept
    one (``keep``), or a new one closed by ``cleanup``."""
    from envs.joint_env import JointControlEnv  # heavy: the joint-control env, only for a replay check

    key = (f"{task}/replay", int(steps))
    if keep and key in _KEPT:
        return _KEPT[key][0]
    stack = ExitStack()
    env = JointControlEnv(task, steps=int(steps))
    stack.callback(env.close)
    if keep:
        _KEPT[key] = (env, None, stack)
    else:
        cleanup.push(stack)
    return env


def _drop_environment(task: str, n_frames: int) -> None:
    """Close the task's kept envs (after an attempt raised: the next attempt gets fresh ones)."""
    for key in [k for k in _KEPT if k == (task, int(n_frames)) or k[0] == f"{task}/replay"]:
        _KEPT.pop(key)[2].close()


def run_shard(spec: ShardSpec, progress: bool = False, keep_env: bool = False) -> ShardResult:
    """Run (or resume) one shard until it holds ``spec.n_success`` demos, or until ``spec.round_end``.

    ``keep_env``: leave the environment open in this process for the next call (a worker's)."""
    t0 = time.perf_counter()
    spec.dir.mkdir(parents=True, exist_ok=True)
    rows = resume_attempts(spec.dir)
    for torn in spec.dir.glob(".ep*.npz.tmp"):  # a demo write cut by a kill; its attempt is re-run
        torn.unlink()
    done = {r["attempt"] for r in rows}
    successes = sum(r["success"] for r in rows)
    attempt = len(rows)
    plb = load_plb()
    prior = plb.prior(spec.task)
    probs = as_probs(spec.proposal) if spec.proposal is not None else prior
    replays = np.asarray(spec.replays, dtype=np.int64).reshape(-1, len(prior))  # once, not per attempt
    replay_weights = np.asarray(spec.replay_weights, dtype=np.float64) if spec.replay_weights else None
    end = spec.call_end

    measure_key = task_class(spec.task).measure_key  # nail descent, cubes in the zone, cap turn
    env = executor = None
    cleanup = ExitStack()
    bar = None
    if progress:
        bar = tqdm(total=spec.n_success, initial=successes, desc=f"{spec.task} shard {spec.shard}", unit="demo")
    try:
        while successes < spec.n_success and attempt < end:
            demo_path = spec.dir / f"ep{attempt:06d}.npz"
            scene_seed, plan_seed = attempt_seeds(spec.run_seed, spec.task, spec.shard, attempt)
            if attempt not in done and demo_path.exists():  # killed after the demo, before its line
                demo = load_demo(demo_path)
                plan = [int(v) for v in demo.plan]
                row = {"attempt": attempt, "seed": scene_seed, "plan": plan,
                       **_logps(spec, probs, prior, plan, replays, replay_weights), "success": True,
                       "measure": float(demo.outcome.get(measure_key, float("nan")))}
            else:
                if env is None:
                    env, executor = _environment(spec.task, spec.n_frames, keep_env, cleanup)
                rng = np.random.default_rng(plan_seed)
                plan = sample_plan(probs, rng) if spec.defensive is None else \
                    sample_mixture(prior, probs, spec.defensive, rng, replays, spec.replay, replay_weights)
                texts = plb.texts(spec.task)
                text = texts[int(rng.integers(len(texts)))]
                row = {"attempt": attempt, "seed": scene_seed, "plan": [int(v) for v in plan],
                       **_logps(spec, probs, prior, plan, replays, replay_weights)}
                try:
                    result = executor.run(plan, seed=scene_seed)
                    replayed = True
                    if result.success:
                        demo = from_episode(spec.task, scene_seed, text, result, env,
                                            proposal_logp=row["proposal_logp"], prior_logp=row["prior_logp"])
                        if spec.replay_check:
                            steps = int(np.asarray(demo.stage).shape[0])
                            replayed = demo_replays(_replay_environment(spec.task, steps, keep_env, cleanup), demo)
                        if replayed:
                            save_demo(demo, demo_path)
                except Exception as exc:  # noqa: BLE001 - one attempt's error must not end the run
                    row |= {"success": False, "measure": float("nan"), "error": error_text(exc)}
                    _log.warning("%s shard %d attempt %d raised: %s", spec.task, spec.shard, attempt, row["error"])
                    cleanup.close()  # a fresh environment for the next attempt
                    cleanup = ExitStack()
                    _drop_environment(spec.task, spec.n_frames)
                    env = executor = None
                else:
                    row |= {"success": bool(result.success) and replayed,
                            "measure": float(result.outcome.get(measure_key, float("nan")))}
                    if not replayed:  # succeeded, but not by its 50 Hz replay: no demo
                        row["replayed"] = False
                    if result.fault and not result.success:  # (a demo's row, rebuilt after a kill, has none)
                        row["fault"] = result.fault
                    if result.decided:  # ended early: its measure is the one at the early end
                        row |= {"decided": result.decided, "frames": int(result.frames_stepped)}
            _append(spec.dir, row)
            successes += row["success"]
            attempt += 1
            if bar is not None:
                bar.update(int(row["success"]))
                bar.set_postfix(attempts=attempt, yield_=f"{successes / attempt:.2f}")
    finally:
        if bar is not None:
            bar.close()
        cleanup.close()
    return replace(shard_result(spec), seconds=time.perf_counter() - t0)


def _logps(spec: ShardSpec, probs: Any, prior: Any, plan: Any, replays: np.ndarray,
           replay_weights: np.ndarray | None) -> dict[str, Any]:
    """The attempt's round and its plan's log-probabilities under the distribution that drew it and the prior
    (``replays``, ``replay_weights``: ``spec.replays`` and ``spec.replay_weights`` as arrays)."""
    drew = log_prob(probs, plan) if spec.defensive is None else \
        mixture_log_prob(prior, probs, spec.defensive, plan, replays, spec.replay, replay_weights)
    return {"round": int(spec.round), "proposal_logp": drew, "prior_logp": log_prob(prior, plan)}


def shard_result(spec: ShardSpec) -> ShardResult:
    """What a shard holds on disk."""
    rows = read_attempts(spec.dir)
    return ShardResult(task=spec.task, shard=spec.shard, attempts=len(rows), successes=sum(r["success"] for r in rows),
                       demo_paths=tuple(sorted(spec.dir.glob("ep*.npz"))), errors=sum("error" in r for r in rows))


def round_specs(specs: Sequence[ShardSpec], cfg: ProposalConfig) -> tuple[int, list[ShardSpec]]:
    """The next round of a run: its index and, for every unfinished shard, its spec for that round with the
    round's proposal (``prl.proposal.round_proposals`` over the attempt logs of the earlier rounds). A prior
    run is one round without limit. ``(-1, [])`` when every shard is done."""
    logs = {(s.task, s.shard): read_attempts(s.dir) for s in specs}
    todo = [s for s in specs if not s.done(len(logs[s.task, s.shard]),
                                           sum(r["success"] for r in logs[s.task, s.shard]))]
    if not todo:
        return -1, []
    if cfg.kind == "prior":
        return 0, longest_first([replace(s, proposal=None, round=0, round_end=None) for s in todo], logs)
    r = min(len(logs[s.task, s.shard]) // cfg.round_attempts for s in todo)
    plb = load_plb()
    out = []
    proposals: dict[str, Any] = {}
    replays: dict[str, tuple[tuple[int, ...], ...]] = {}
    replay_weights: dict[str, tuple[float, ...]] = {}
    for s in todo:
        if len(logs[s.task, s.shard]) >= (r + 1) * cfg.round_attempts:  # ended this round before a kill
            continue
        if s.task not in proposals:
            rows = [row for t in specs if t.task == s.task for row in logs[t.task, t.shard]]  # shard order
            won = [[row for row in rows if row["success"] and row["attempt"] // cfg.round_attempts == k]
                   for k in range(r)]
            by_round = [np.array([row["plan"] for row in b], dtype=np.int64) for b in won]
            weights = _success_weights(won) if cfg.weighted else None
            proposals[s.task] = round_proposals(plb.prior(s.task), by_round, cfg, weights)[r]
            replays[s.task] = tuple(tuple(int(v) for v in p) for b in by_round for p in b) if cfg.replay else ()
            replay_weights[s.task] = tuple(float(v) for b in weights for v in b) if cfg.replay and weights else ()
        out.append(replace(s, proposal=tuple(tuple(float(v) for v in p) for p in proposals[s.task]), round=r,
                           round_end=(r + 1) * cfg.round_attempts, defensive=cfg.defensive,
                           replays=replays[s.task], replay=cfg.replay, replay_weights=replay_weights[s.task]))
    return r, longest_first(out, logs)


def _success_weights(won: Sequence[Sequence[dict[str, Any]]]) -> list[np.ndarray]:
    """Per round, the importance weights ``p / m`` of its successful attempts' plans (``prl.stats.importance_weights``
    over the successes of all rounds together: one common scale, mean 1)."""
    rows = [row for b in won for row in b]
    w = importance_weights([row["prior_logp"] for row in rows], [row["proposal_logp"] for row in rows]) \
        if rows else np.zeros(0)
    return list(np.split(w, np.cumsum([len(b) for b in won])[:-1])) if won else []


def expected_attempts(spec: ShardSpec, attempts: int, successes: int, yield_: float) -> float:
    """Attempts a shard with these counts is expected to make in ``spec``'s call: its missing demos over the
    task's yield so far (1 when unknown), capped by the attempts left in the round and overall."""
    left = spec.call_end - attempts
    need = max(spec.n_success - successes, 0) / max(yield_, 1.0 / spec.max_attempts)
    return float(max(min(left, need), 0))


def longest_first(todo: list[ShardSpec], logs: dict[tuple[str, int], list[dict]]) -> list[ShardSpec]:
    """``todo`` with the shards expected to run longest first (``expected_attempts``, stable): workers take
    shard-rounds in submission order, and a round that starts its longest shard last ends waiting for it
    while the other workers idle. The order changes no attempt (module docstring)."""
    rows = {t: [r for (task, _), rs in logs.items() if task == t for r in rs] for t in {s.task for s in todo}}
    yields = {t: (sum(r["success"] for r in rs) / len(rs) if rs else 1.0) for t, rs in rows.items()}

    def cost(s: ShardSpec) -> float:
        log = logs[s.task, s.shard]
        return expected_attempts(s, len(log), sum(r["success"] for r in log), yields[s.task])

    return sorted(todo, key=cost, reverse=True)


def rounds_by_task(specs: Sequence[ShardSpec], cfg: ProposalConfig, start: Callable[[list[ShardSpec]], Any],
                   collect: Callable[[Any], list[ShardResult] | None], idle: Callable[[], None],
                   on_round: Callable[[int, list[ShardResult]], None] | None = None) -> list[ShardResult]:
    """Run (or resume) a synthesis run, each task's rounds on their own: a task's round r + 1 starts as soon as
    the task's round r has ended in all its shards, whatever the other tasks' rounds (a task's proposal reads
    only its own attempts, so the attempts are those of the tasks in lockstep). ``start(todo)`` launches one
    task's round (``round_specs``) and returns a handle; ``collect(handle)`` returns the round's results once it
    has ended, else None; ``idle()`` is called when no round has ended since the last look; ``on_round(round,
    results)`` after each round. Returns each spec's ``shard_result`` at the end, in the order of ``specs``."""
    groups: dict[str, list[ShardSpec]] = {}
    for spec in specs:
        groups.setdefault(spec.task, []).append(spec)
    running: dict[str, tuple[int, Any]] = {}

    def launch(task: str) -> None:
        r, todo = round_specs(groups[task], cfg)
        if todo:
            running[task] = (r, start(todo))
        else:
            running.pop(task, None)

    for task in groups:
        launch(task)
    while running:
        ended = False
        for task, (r, handle) in list(running.items()):
            results = collect(handle)
            if results is None:
                continue
            ended = True
            if on_round is not None:
                on_round(r, results)
            launch(task)
        if not ended:
            idle()
    return [shard_result(s) for s in specs]


def synthesize_rounds(specs: Sequence[ShardSpec], cfg: ProposalConfig,
                      run: Callable[[list[ShardSpec]], list[ShardResult]],
                      on_round: Callable[[int, list[ShardResult]], None] | None = None) -> list[ShardResult]:
    """``rounds_by_task`` with a ``run`` that executes one task's round at once (in this process) and returns its
    results."""
    return rounds_by_task(specs, cfg, run, lambda results: results, lambda: None, on_round)


def task_attempts(out_dir: Path, task: str) -> list[dict]:
    """Every finished attempt of ``task`` in a synthesis directory, shard by shard in shard order."""
    return [r for d in sorted((Path(out_dir) / task).glob("shard*")) for r in read_attempts(d)]


def yield_report(out_dir: Path, task: str, n_frames: int = EPISODE_FRAMES) -> dict[str, float]:
    """Yield (successes / attempts) overall and per plan dimension choice, attempts that raised (``errors``), that
    the executor ended itself (``faults/<fault>``), that ended early as decided failures (``decided``) and that
    succeeded but not by their replay (``not_replayed``, ``ShardSpec.replay_check``), and the plan-episode physics
    frames stepped per attempt (``n_frames`` each, but those ended early), from the attempt logs."""
    rows = task_attempts(out_dir, task)
    report: dict[str, float] = {"attempts": float(len(rows)), "successes": float(sum(r["success"] for r in rows))}
    report["yield"] = report["successes"] / report["attempts"] if rows else 0.0
    report["errors"] = float(sum("error" in r for r in rows))
    report["decided"] = float(sum("decided" in r for r in rows))
    report["not_replayed"] = float(sum(r.get("replayed") is False for r in rows))
    report["frames_per_attempt"] = float(np.mean([r.get("frames", n_frames) for r in rows])) if rows else 0.0
    for fault in FAULTS:
        report[f"faults/{fault}"] = float(sum(r.get("fault") == fault for r in rows))
    plb = load_plb()
    for i, dim in enumerate(plb.dims):
        for c in range(dim.size):
            picked = [r["success"] for r in rows if r["plan"][i] == c]
            if picked:
                report[f"yield/{dim.name}/{c}"] = float(np.mean(picked))
    return report
