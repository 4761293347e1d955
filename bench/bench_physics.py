"""Benchmark (not a test): physics settings of a plan episode, cost and fidelity (executor-v2 issue, part 3).

Two measurements, each taken side by side in one process:

``cost``  -- the machine-independent cost of one attempt: the median wall time of an attempt (reset +
observation phase + plan episode on the hammer, expert and prior-sampled plans alternating, fresh
scene each) divided by the time of a fixed yardstick measured in the same run, in rotating order:
ManiSkill's ``PickCube-v1`` (physx_cpu, its default sim config) stepped 400 times with a fixed
action sequence. Run for the pipeline's physics settings and, with ``--settings``, others.

``fidelity`` -- fixed (scene, plan) pairs (expert, prior-sampled and uniform plans in turn) run under
several physics settings ``<Hz>/<position iterations>`` over the same simulated duration (3 s); each
setting's successes are compared with a converged reference (the first setting). Results are appended
per pair to ``<out>/<setting>.jsonl``, so a killed run resumes where it stopped.

    python -m bench.bench_physics cost [--rounds 12] [--settings 500/25,250/12] [--tasks hammer,sweep]
    python -m bench.bench_physics fidelity [--pairs 210] [--settings 1000/50,500/25,250/12] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # ``python bench/bench_physics.py``
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp/prl-runtime")
os.makedirs(os.environ["XDG_RUNTIME_DIR"], exist_ok=True)

import numpy as np
from tqdm.auto import tqdm

YARDSTICK_STEPS = 400


def parse_setting(text: str) -> tuple[int, int]:
    """``"250/12"`` -> (250, 12); ``ValueError`` naming the text otherwise."""
    try:
        hz, iterations = (int(v) for v in text.split("/"))
    except ValueError as exc:
        raise ValueError(f"a physics setting is '<Hz>/<position iterations>', e.g. 250/12; got {text!r}") from exc
    if hz <= 0 or iterations <= 0:
        raise ValueError(f"Hz and iterations must be positive, got {text!r}")
    return hz, iterations


def make_task_env(task: str, setting: tuple[int, int] | None) -> Any:
    """The task env with the given physics setting (None: the pipeline's own)."""
    import envs.agents  # noqa: F401
    from envs.tasks import make_env, physics_sim_config

    return make_env(task) if setting is None else make_env(task, sim_config=physics_sim_config(*setting))


def yardstick_seconds(env: Any, actions: np.ndarray) -> float:
    """Seconds of ``PickCube-v1``: reset(seed=0) and ``len(actions)`` ``env.step`` calls."""
    t0 = time.perf_counter()
    env.reset(seed=0)
    for a in actions:
        env.step(a)
    return time.perf_counter() - t0


def cost(rounds: int, settings: list[tuple[int, int] | None], tasks: tuple[str, ...] = ("hammer",)) -> None:
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401  (registers PickCube-v1)

    from envs.execution import ExecutorConfig
    from envs.executor import PlanExecutor
    from envs.tasks import fast_resets
    from envs.trials import plan_set

    stick = gym.make("PickCube-v1", num_envs=1, sim_backend="physx_cpu", obs_mode="state", render_mode=None)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(YARDSTICK_STEPS, *stick.action_space.shape)).astype(np.float32)
    plans = {task: [p for pair in zip(plan_set(task, "expert", rounds, 0), plan_set(task, "prior", rounds, 1))
                    for p in pair] for task in tasks}
    runners = []
    for task in tasks:
        for setting in settings:
            env = make_task_env(task, setting)
            runners.append((task, setting, env, PlanExecutor(env, ExecutorConfig(record_every=5))))
    yard: list[float] = []
    per: dict[Any, list[float]] = {(t, s): [] for t, s, _, _ in runners}
    with fast_resets():
        for task, _, _, executor in runners:  # warm-up: imports, IK model, first scene
            executor.run(plans[task][0], seed=999)
        yardstick_seconds(stick, actions[:20])
        for i in range(2 * rounds):
            order = list(range(len(runners) + 1))
            order = order[i % len(order):] + order[: i % len(order)]
            for k in order:
                if k == len(runners):
                    yard.append(yardstick_seconds(stick, actions))
                    continue
                task, setting, _, executor = runners[k]
                t0 = time.perf_counter()
                executor.run(plans[task][i], seed=10_000 + i)
                per[task, setting].append(time.perf_counter() - t0)
    y = statistics.median(yard)
    print(f"yardstick PickCube-v1, {YARDSTICK_STEPS} env.step (median of {len(yard)}): {y:.3f} s")
    ratios = {}
    for task, setting, _, executor in runners:
        name = "pipeline" if setting is None else f"{setting[0]}/{setting[1]}"
        a = statistics.median(per[task, setting])
        ratios[task, setting] = a / y
        print(f"{task} attempt, {name:>8} ({executor.config.n_frames} frames, {executor.sim_freq} Hz): "
              f"median {a:.3f} s over {len(per[task, setting])} -> ratio {a / y:.2f}")
    for task in tasks[1:]:
        for setting in settings:
            print(f"{task} / {tasks[0]} attempt cost ({'pipeline' if setting is None else setting}): "
                  f"{ratios[task, setting] / ratios[tasks[0], setting]:.2f}x")
    for _, _, env, _ in runners:
        env.close()
    stick.close()


def pairs(n: int, seed: int = 0) -> list[tuple[int, str, tuple[int, ...]]]:
    """``n`` fixed (scene seed, kind, plan) pairs, kinds in turn."""
    from envs.trials import PLAN_KINDS, plan_set  # heavy: loads the simulator

    per_kind = {k: plan_set("hammer", k, n, seed + i) for i, k in enumerate(PLAN_KINDS)}
    return [(20_000 + i, PLAN_KINDS[i % 3], per_kind[PLAN_KINDS[i % 3]][i]) for i in range(n)]


def carry_slip_mm(result: Any) -> float | None:
    """How far (mm) the tool moved in the palm's frame from the end of the lift to the end of the transport,
    if the hand held it at the end of the lift (>= 3 sensors over 0.5 N); None otherwise."""
    import sapien  # heavy: the simulator

    from prl.stages import STAGES

    lift = np.flatnonzero(result.stage == STAGES.index("lift"))
    carry = np.flatnonzero(result.stage == STAGES.index("transport"))
    if not lift.size or not carry.size or (result.force[lift[-1]] > 0.5).sum() < 3:
        return None

    def tool_in_palm(k: int) -> np.ndarray:
        palm = sapien.Pose(result.palm_pose[k, :3], result.palm_pose[k, 3:])
        tool = sapien.Pose(result.tool_pose[k, :3], result.tool_pose[k, 3:])
        return np.asarray((palm.inv() * tool).p, dtype=np.float64)

    return float(np.linalg.norm(tool_in_palm(carry[-1]) - tool_in_palm(lift[-1])) * 1000.0)


def fidelity(n: int, settings: list[tuple[int, int]], out: Path) -> None:
    from envs.execution import ExecutorConfig  # heavy: loads the simulator
    from envs.executor import PlanExecutor
    from envs.tasks import fast_resets

    out.mkdir(parents=True, exist_ok=True)
    todo = pairs(n)
    for setting in settings:
        path = out / f"{setting[0]}-{setting[1]}.jsonl"
        done = {json.loads(line)["seed"] for line in path.read_text().splitlines()} if path.exists() else set()
        rest = [p for p in todo if p[0] not in done]
        if not rest:
            continue
        env = make_task_env("hammer", setting)
        executor = PlanExecutor(env, ExecutorConfig(record_every=5))  # records are not compared, only outcomes
        with fast_resets(), open(path, "a") as fh:
            for seed, kind, plan in tqdm(rest, desc=f"{setting[0]} Hz / {setting[1]} it", unit="pair"):
                t0 = time.perf_counter()
                r = executor.run(plan, seed=seed)
                fh.write(json.dumps({"seed": seed, "kind": kind, "plan": list(plan), "success": bool(r.success),
                                     "measure": float(r.outcome["nail_descent_cm"]), "blowup": bool(r.outcome["blowup"]),
                                     "carry_slip_mm": carry_slip_mm(r), "seconds": time.perf_counter() - t0}) + "\n")
                fh.flush()
        env.close()
    report(out, settings, n)


def report(out: Path, settings: list[tuple[int, int]], n: int) -> None:
    from envs.trials import PLAN_KINDS  # heavy: loads the simulator

    rows = {}
    for s in settings:
        path = out / f"{s[0]}-{s[1]}.jsonl"
        rows[s] = {r["seed"]: r for r in map(json.loads, path.read_text().splitlines())}
    ref = rows[settings[0]]
    seeds = [seed for seed, _, _ in pairs(n) if all(seed in rows[s] for s in settings)]
    print(f"{len(seeds)} (scene, plan) pairs, reference {settings[0][0]} Hz / {settings[0][1]} iterations")
    print("| setting | agree with reference (d > 0.05 cm) | agree on d > 1 cm | expert | prior | uniform | blow-ups "
          "| carry slip mm, median / p90 (held) | median s/attempt |")
    print("|---|---|---|---|---|---|---|---|---|")
    for s in settings:
        r = rows[s]
        agree = sum(r[k]["success"] == ref[k]["success"] for k in seeds)
        agree_1cm = sum((r[k]["measure"] > 1.0) == (ref[k]["measure"] > 1.0) for k in seeds)
        rate = {kind: (sum(r[k]["success"] for k in seeds if r[k]["kind"] == kind),
                       sum(1 for k in seeds if r[k]["kind"] == kind)) for kind in PLAN_KINDS}
        print(f"| {s[0]} Hz / {s[1]} | {agree}/{len(seeds)} | {agree_1cm}/{len(seeds)} | "
              + " | ".join(f"{a}/{b}" for a, b in rate.values())
              + f" | {sum(r[k]['blowup'] for k in seeds)} | {slip_text(r, seeds)}"
              + f" | {statistics.median(r[k]['seconds'] for k in seeds):.2f} |")


def slip_text(rows: dict[int, dict], seeds: list[int]) -> str:
    slips = [rows[k]["carry_slip_mm"] for k in seeds if rows[k].get("carry_slip_mm") is not None]
    return f"{np.median(slips):.1f} / {np.percentile(slips, 90):.1f} (n={len(slips)})" if slips else "-"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", choices=("cost", "fidelity", "report"))
    parser.add_argument("--rounds", type=int, default=12, help="cost: attempts per plan kind and setting")
    parser.add_argument("--pairs", type=int, default=210, help="fidelity: (scene, plan) pairs")
    parser.add_argument("--settings", default=None, help="comma-separated <Hz>/<iterations>")
    parser.add_argument("--out", type=Path, default=Path("outputs/bench/physics_fidelity"))
    parser.add_argument("--tasks", default="hammer", help="cost: comma-separated tasks, the first is the reference")
    args = parser.parse_args(argv)
    if args.what == "cost":
        extra = [parse_setting(t) for t in args.settings.split(",")] if args.settings else []
        cost(args.rounds, [None, *extra], tuple(t.strip() for t in args.tasks.split(",") if t.strip()))
        return
    settings = [parse_setting(t) for t in (args.settings or "1000/50,500/25,250/12").split(",")]
    if args.what == "fidelity":
        fidelity(args.pairs, settings, args.out)
    else:
        report(args.out, settings, args.pairs)


if __name__ == "__main__":
    main()
