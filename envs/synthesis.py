"""Scene synthesis: domain-randomised scenes x plans sampled from the task prior -> kept demos.

Work is split into a fixed number of shards. Attempt ``j`` of shard ``k`` uses a scene seed and
a plan drawn from generators seeded by ``(run seed, task, k, j)`` only, so the result does not
depend on how many workers run the shards, nor on the order they run in. A shard stops when it
has its share of successes (or ``max_attempts`` attempts).

On disk, per shard ``<out>/<task>/shard<k>/``:

* ``attempts.jsonl`` - one line per finished attempt (seed, plan, success, measure; ``fault`` when the
  executor ended a failed plan itself, ``error`` with the exception text when the attempt raised), appended
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
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from envs.execution import ExecutorConfig
from envs.executor import PlanExecutor
from envs.tasks import fast_resets, make_env, task_class
from envs.trials import error_text
from prl.constants import EPISODE_FRAMES
from prl.demo import from_episode, load_demo, save_demo
from prl.plb import load_plb
from prl.stages import FAULTS

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

    def __post_init__(self) -> None:
        if self.n_success < 0:
            raise ValueError(f"n_success must be >= 0, got {self.n_success!r}")
        if self.max_attempts <= 0:
            raise ValueError(f"max_attempts must be > 0, got {self.max_attempts!r}")

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
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            break  # a line cut by a kill: that attempt is re-run
    return rows


def _append(shard_dir: Path, row: dict) -> None:
    with open(Path(shard_dir) / "attempts.jsonl", "a") as fh:
        fh.write(json.dumps(row) + "\n")
        fh.flush()


def run_shard(spec: ShardSpec, progress: bool = False) -> ShardResult:
    """Run (or resume) one shard until it holds ``spec.n_success`` demos."""
    spec.dir.mkdir(parents=True, exist_ok=True)
    path = spec.dir / "attempts.jsonl"
    rows = read_attempts(spec.dir)
    if path.exists():  # rewrite without a torn tail so appends stay line-aligned
        path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    for torn in spec.dir.glob(".ep*.npz.tmp"):  # a demo write cut by a kill; its attempt is re-run
        torn.unlink()
    done = {r["attempt"] for r in rows}
    successes = sum(r["success"] for r in rows)
    attempt = len(rows)
    plb = load_plb()

    measure_key = task_class(spec.task).measure_key  # nail descent, cubes in the zone, cap turn
    env = executor = None
    cleanup = ExitStack()
    bar = None
    if progress:
        bar = tqdm(total=spec.n_success, initial=successes, desc=f"{spec.task} shard {spec.shard}", unit="demo")
    try:
        while successes < spec.n_success and attempt < spec.max_attempts:
            demo_path = spec.dir / f"ep{attempt:06d}.npz"
            scene_seed, plan_seed = attempt_seeds(spec.run_seed, spec.task, spec.shard, attempt)
            if attempt not in done and demo_path.exists():  # killed after the demo, before its line
                demo = load_demo(demo_path)
                row = {"attempt": attempt, "seed": scene_seed, "plan": demo.plan.tolist(), "success": True,
                       "measure": float(demo.outcome.get(measure_key, float("nan")))}
            else:
                if env is None:
                    env = make_env(spec.task)
                    cleanup.callback(env.close)
                    cleanup.enter_context(fast_resets())
                    executor = PlanExecutor(env, ExecutorConfig(n_frames=spec.n_frames))
                rng = np.random.default_rng(plan_seed)
                plan = plb.sample_plan(spec.task, rng)
                texts = plb.texts(spec.task)
                text = texts[int(rng.integers(len(texts)))]
                row = {"attempt": attempt, "seed": scene_seed, "plan": [int(v) for v in plan]}
                try:
                    result = executor.run(plan, seed=scene_seed)
                    if result.success:
                        save_demo(from_episode(spec.task, scene_seed, text, result, env), demo_path)
                except Exception as exc:  # noqa: BLE001 - one attempt's error must not end the run
                    row |= {"success": False, "measure": float("nan"), "error": error_text(exc)}
                    _log.warning("%s shard %d attempt %d raised: %s", spec.task, spec.shard, attempt, row["error"])
                    cleanup.close()  # a fresh environment for the next attempt
                    cleanup = ExitStack()
                    env = executor = None
                else:
                    row |= {"success": bool(result.success),
                            "measure": float(result.outcome.get(measure_key, float("nan")))}
                    if result.fault and not result.success:  # (a demo's row, rebuilt after a kill, has none)
                        row["fault"] = result.fault
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
    demos = tuple(sorted(spec.dir.glob("ep*.npz")))
    errors = sum("error" in r for r in read_attempts(spec.dir))
    return ShardResult(task=spec.task, shard=spec.shard, attempts=attempt, successes=successes, demo_paths=demos,
                       errors=errors)


def yield_report(out_dir: Path, task: str) -> dict[str, float]:
    """Yield (successes / attempts) overall and per plan dimension choice, attempts that raised
    (``errors``) and that the executor ended itself (``faults/<fault>``), from the attempt logs."""
    rows = [r for d in sorted((Path(out_dir) / task).glob("shard*")) for r in read_attempts(d)]
    report: dict[str, float] = {"attempts": float(len(rows)), "successes": float(sum(r["success"] for r in rows))}
    report["yield"] = report["successes"] / report["attempts"] if rows else 0.0
    report["errors"] = float(sum("error" in r for r in rows))
    for fault in FAULTS:
        report[f"faults/{fault}"] = float(sum(r.get("fault") == fault for r in rows))
    plb = load_plb()
    for i, dim in enumerate(plb.dims):
        for c in range(dim.size):
            picked = [r["success"] for r in rows if r["plan"][i] == c]
            if picked:
                report[f"yield/{dim.name}/{c}"] = float(np.mean(picked))
    return report
