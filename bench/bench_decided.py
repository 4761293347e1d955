"""Ending decided failures early (``ExecutorConfig.end_decided``) against full episodes, attempt by attempt:
``python -m bench.bench_decided --task hammer --attempts 500 [--out /tmp/decided_hammer.jsonl]``.

The attempts are those of a synthesis run (``envs.synthesis.run_shard``): attempt j of shard ``--shard`` of run
``--run-seed`` has the scene seed and the prior-sampled plan of ``attempt_seeds(run_seed, task, shard, j)``. Each
one runs twice in the same process, reset included, in alternating order: with full episodes (off) and with the
early end (on). Checked and printed:

* the success of every attempt is the same both ways (the early end must never change an outcome: any
  mismatch is listed);
* physics frames per attempt (the observation phase + the plan episode's stepped frames) and the time per
  attempt both ways (CPU time of the process, which other processes on the machine do not inflate, and wall
  time), their ratios, and the CPU time the decisions themselves took;
* for each attempt ended early, what the full episode did after that point: how far the moving bodies (the
  recorded ``scene_pose``/``scene_qpos``) moved from then on, and the smallest distance between the hand (its
  recorded joints, every recorded frame) and those bodies where they were at the early end, next to the
  clearance the decision saw. The rule assumes the bodies stay put and the hand stays clear of them.

One line per attempt is appended to ``--out`` as it finishes, and attempts already there are skipped, so a run
can be stopped and resumed; the summary is computed from the whole file. One simulation process: run one task
at a time.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # ``python bench/bench_decided.py``
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp/prl-runtime")
os.makedirs(os.environ["XDG_RUNTIME_DIR"], exist_ok=True)

import numpy as np

from envs.execution import ExecutorConfig
from envs.executor import PlanExecutor
from envs.reach import REACH_MARGIN, body_capsules, capsule_clearance, hand_capsules, moving_bodies
from envs.synthesis import attempt_seeds
from envs.tasks import fast_resets, make_env
from prl.constants import EPISODE_FRAMES
from prl.plb import load_plb


def hand_clearance(env: Any, qpos: np.ndarray, bodies: np.ndarray) -> float:
    """Smallest distance (m) between the hand at the joint vectors ``qpos`` (K, 30) and the capsules ``bodies``."""
    if not len(qpos):
        return float("inf")
    root = np.asarray(env.agent.robot._objs[0].get_root_pose().to_transformation_matrix(), dtype=np.float64)
    return capsule_clearance(hand_capsules(env, qpos, root), bodies)


def _clearance_in(reason: str) -> float:
    """The clearance (m) a frozen-scene decision states ("... 20 cm or more ..."), NaN if it states none."""
    words = reason.split(" cm or more")[0].split()
    try:
        return float(words[-1]) / 100.0
    except (IndexError, ValueError):
        return float("nan")


def run_attempt(env: Any, off: PlanExecutor, on: PlanExecutor, plan: np.ndarray, seed: int, on_first: bool) -> dict:
    """Both runs of one attempt and what the full one did after the early end."""
    inner = env.unwrapped
    out: dict[str, Any] = {}
    snapshot = None
    asked = inner.failure_decided
    spent = [0.0]

    def timed(stage: str, reach: Any) -> str:  # the decisions' own cost, as CPU time
        c = time.process_time()
        try:
            return asked(stage, reach)
        finally:
            spent[0] += time.process_time() - c

    for name in (("on", "off") if on_first else ("off", "on")):
        executor = on if name == "on" else off
        inner.failure_decided = timed  # an instance attribute: what the episode calls
        t, c = time.perf_counter(), time.process_time()
        try:
            result = executor.run(plan, seed=seed)
        finally:
            del inner.failure_decided
        out[f"t_{name}"] = time.perf_counter() - t
        out[f"cpu_{name}"] = time.process_time() - c
        out[f"success_{name}"] = bool(result.success)
        out[f"frames_{name}"] = int(executor.config.observe_frames + result.frames_stepped)
        out[f"result_{name}"] = result
        if name == "on" and result.decided:  # the bodies where the early end left them
            snapshot = np.concatenate([body_capsules(b) for b in moving_bodies(inner)])
    out["cpu_deciding"] = spent[0]
    full, early = out.pop("result_off"), out.pop("result_on")
    out["decided"] = early.decided
    if early.decided and snapshot is not None and " cm or more " in early.decided:  # a frozen-scene decision
        first = early.frames_stepped  # the first frame the early end did not step
        after = full.frame >= first
        pose = full.scene_pose[after]
        qpos = full.scene_qpos[after]
        out["moved_after_m"] = float(np.max(np.linalg.norm(pose[:, :, :3] - pose[:1, :, :3], axis=2))) if len(pose) else 0.0
        out["joints_moved_after"] = float(np.max(np.abs(qpos - qpos[:1]))) if qpos.size else 0.0
        out["hand_clearance_after_m"] = hand_clearance(inner, full.qpos[after], snapshot)
        out["clearance_seen_m"] = _clearance_in(early.decided)
    return out


def summarize(rows: list[dict]) -> str:
    """The check's summary over ``rows`` (one per attempt)."""
    n = len(rows)
    if not n:
        return "no attempts"
    same = sum(r["success_off"] == r["success_on"] for r in rows)
    mismatches = [r["attempt"] for r in rows if r["success_off"] != r["success_on"]]
    decided = [r for r in rows if r["decided"]]
    f_off, f_on = (float(np.mean([r[k] for r in rows])) for k in ("frames_off", "frames_on"))
    t_off, t_on = (float(np.mean([r[k] for r in rows])) for k in ("t_off", "t_on"))
    c_off, c_on, c_dec = (float(np.mean([r[k] for r in rows])) for k in ("cpu_off", "cpu_on", "cpu_deciding"))
    lines = [
        (f"{rows[0]['task']}: {n} attempts, successes {sum(r['success_off'] for r in rows)} full / "
         f"{sum(r['success_on'] for r in rows)} with the early end; identical success in {same} of {n}"
         + (f"; MISMATCHES at attempts {mismatches}" if mismatches else "")),
        (f"  ended early: {len(decided)} ({len(decided) / n:.1%}; of the failures "
         f"{len(decided) / max(1, sum(not r['success_off'] for r in rows)):.1%})"),
        f"  physics frames per attempt: {f_off:.1f} full -> {f_on:.1f} ({f_on / f_off:.3f}x)",
        (f"  CPU time per attempt (reset, observation, episode): {c_off * 1e3:.0f} ms full -> {c_on * 1e3:.0f} ms "
         f"({c_on / c_off:.3f}x), of which {c_dec * 1e3:.1f} ms deciding; wall time {t_off * 1e3:.0f} -> "
         f"{t_on * 1e3:.0f} ms ({t_on / t_off:.3f}x)"),
    ]
    if decided:
        by_stage: dict[str, int] = {}
        for r in decided:
            key = r["decided"].split(":")[0]
            by_stage[key] = by_stage.get(key, 0) + 1
        lines.append("  ended " + ", ".join(f"{k}: {v}" for k, v in sorted(by_stage.items())))
        frozen = [r for r in decided if "hand_clearance_after_m" in r]
        if frozen:
            moved = max(r["moved_after_m"] for r in frozen)
            joints = max(r["joints_moved_after"] for r in frozen)
            clear = min(r["hand_clearance_after_m"] for r in frozen)
            closer = max(r["clearance_seen_m"] - r["hand_clearance_after_m"] for r in frozen)
            lines.append(f"  {len(frozen)} ended with every body asleep out of reach; after that, in their full "
                         f"episodes: bodies moved <= {moved * 1e3:.2f} mm, mechanism joints <= {joints:.2e}, the hand "
                         f"stayed >= {clear * 100:.1f} cm from them (at most {closer * 100:.1f} cm closer than the "
                         f"decision's path said, margin {REACH_MARGIN * 100:.0f} cm)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", required=True)
    parser.add_argument("--attempts", type=int, default=500)
    parser.add_argument("--run-seed", type=int, default=0)
    parser.add_argument("--shard", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None, help="attempt log (default /tmp/decided_<task>.jsonl)")
    args = parser.parse_args(argv)
    out = args.out or Path(f"/tmp/decided_{args.task}.jsonl")
    rows = [json.loads(line) for line in out.read_text().splitlines() if line.strip()] if out.exists() else []
    rows = [r for r in rows if r["task"] == args.task and r["run_seed"] == args.run_seed and r["shard"] == args.shard]
    done = {r["attempt"] for r in rows}
    todo = [j for j in range(args.attempts) if j not in done]
    if todo:
        plb = load_plb()
        env = make_env(args.task)
        off = PlanExecutor(env, ExecutorConfig(n_frames=EPISODE_FRAMES))
        on = PlanExecutor(env, ExecutorConfig(n_frames=EPISODE_FRAMES, end_decided=True))
        try:
            off.run(env.unwrapped.expert_plan, seed=10**6)  # warm-up: imports, the IK chain
            with fast_resets(), open(out, "a") as fh:
                for j in todo:
                    scene_seed, plan_seed = attempt_seeds(args.run_seed, args.task, args.shard, j)
                    plan = plb.sample_plan(args.task, np.random.default_rng(plan_seed))
                    row = {"task": args.task, "run_seed": args.run_seed, "shard": args.shard, "attempt": j,
                           "seed": scene_seed, "plan": [int(v) for v in plan]}
                    row |= run_attempt(env, off, on, plan, scene_seed, on_first=bool(j % 2))
                    fh.write(json.dumps(row) + "\n")
                    fh.flush()
                    rows.append(row)
                    if row["success_off"] != row["success_on"]:
                        print(f"MISMATCH at attempt {j}: {row}", flush=True)
        finally:
            env.close()
    print(summarize(sorted((r for r in rows if r["attempt"] < args.attempts), key=lambda r: r["attempt"])))


if __name__ == "__main__":
    main()
