"""Benchmark (not a test): plan-executor speed vs raw PhysX and vs ManiSkill's ``env.step``.

On the hammer scene, in one process, measured side by side (docs/guide/design.md "Speed"; results in
docs/archive/speed.md):

(a) raw ``scene.step()`` frames/s on the scene where the hand holds the hammer (the limit);
(b) frames/s of ``PlanExecutor`` running the full expert plan episode (3 s of simulated time, recording
    included), one fresh seed per round; the first (warm-up) episode is excluded;
(c) frames/s of ManiSkill's per-step control path: ``env.step(action)`` with ``pd_joint_pos``
    targets (action = the current drive targets in ``JOINT_NAMES`` order, so the hand keeps
    holding the hammer; 5 physics frames per control step at 250 Hz), from the same held state as (a).

The held state: the executor runs the expert plan on the round's seed up to the last frame of
the ``lift`` stage (``scene.step`` is wrapped to stop the episode right after that frame, before
any transport target is written); the tool is then checked to be above its rack and in contact
with several sensor patches, before and after each measurement. a / b / c are interleaved in
rotating order over a few rounds and medians are reported, plus the ratios b/a and b/c, the
executor's own in-episode ratio ``physics_time_s / wall_time_s`` and the peak RSS.

    python -m bench.bench_executor [--rounds 5] [--frames 750]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path
from typing import Any, Self

if __package__ in (None, ""):  # ``python bench/bench_executor.py``
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp/prl-runtime")
os.makedirs(os.environ["XDG_RUNTIME_DIR"], exist_ok=True)

import numpy as np

from prl.stages import STAGES

EXPERT = (0, 3, 2, 0, 0, 1)
RSS_BUDGET_GB = 1.2
#: A tool counts as held when it is this far (m) above its rest height and touches >= 3 sensors.
HELD_LIFT_M = 0.05
HELD_MIN_SENSORS = 3
HELD_SENSOR_N = 0.5


class _StopAfterFrame(Exception):
    """Raised by the wrapped ``scene.step`` to end an executor episode after a given frame."""


def _peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e9  # Linux: kB


def _lift_end_frame(executor: Any) -> int:
    frames = type(executor.env).stages.stage_frames(executor.config.n_frames)
    return int(np.sum(frames[: STAGES.index("lift") + 1]))


def reach_held_state(env: Any, executor: Any, seed: int) -> dict[str, Any]:
    """Reset to ``seed`` and run the expert plan up to the end of the lift stage.

    Returns the tool's rest height, the drive targets (``JOINT_NAMES`` order) left on the joints
    and the sensor reader. The scene is left exactly as the executor leaves it after its last lift
    frame (nothing is set by hand)."""
    from envs.sensors import ContactSensors  # heavy: loads the simulator

    u = env.unwrapped
    env.reset(seed=int(seed))  # through the gym wrappers, so that env.step() may follow
    rest_z = float(u.tool.pose.raw_pose[0, 2])
    scene = u.scene
    real_step = scene.step
    n_stop = _lift_end_frame(executor)
    count = 0

    def step() -> None:
        nonlocal count
        real_step()
        count += 1
        if count == n_stop:
            raise _StopAfterFrame

    scene.step = step  # instance attribute shadows ManiSkillScene.step for this episode only
    try:
        executor.run(EXPERT, seed=None)
    except _StopAfterFrame:
        pass
    else:  # pragma: no cover
        raise RuntimeError("the episode did not reach the end of the lift stage")
    finally:
        del scene.step
    agent = u.agent
    joints = agent.robot._objs[0].get_active_joints()
    target = np.array([float(np.asarray(joints[i].get_drive_target()).reshape(-1)[0]) for i in agent.joint_perm])
    sensors = ContactSensors(scene, agent.sensor_links, exclude=agent.robot)
    return {"rest_z": rest_z, "target": target, "sensors": sensors, "frames": count}


def held_status(env: Any, held: dict[str, Any]) -> tuple[bool, str]:
    """(held?, description) from the tool height above its rest pose and the contact sensors."""
    u = env.unwrapped
    dz = float(u.tool.pose.raw_pose[0, 2]) - held["rest_z"]
    force = held["sensors"].read()[0]
    n_touch = int((force > HELD_SENSOR_N).sum())
    ok = dz > HELD_LIFT_M and n_touch >= HELD_MIN_SENSORS
    return ok, f"tool +{dz * 100:.1f} cm above rack, {n_touch} sensors > {HELD_SENSOR_N} N, sum {force.sum():.0f} N"


class _NoSleep:
    """Keep the hand articulation and the tool awake (PhysX sleep threshold 0) while measuring.

    A motionless held hammer falls asleep in PhysX after ~1000 frames (re-writing an unchanged drive
    target does not wake it); ``scene.step()`` then costs a few microseconds and measures nothing.
    During an executor episode the drive targets move on nearly every frame, so the bodies stay
    awake; the awake held scene is the meaningful physics limit."""

    def __init__(self, env: Any, enabled: bool) -> None:
        u = env.unwrapped
        self.bodies = [u.agent.robot._objs[0], u.tool._bodies[0]] if enabled else []
        self.saved: list[float] = []

    def __enter__(self) -> Self:
        for body in self.bodies:
            self.saved.append(float(body.get_sleep_threshold()))
            body.set_sleep_threshold(0.0)
        return self

    def __exit__(self, *exc: object) -> None:
        for body, value in zip(self.bodies, self.saved, strict=False):
            body.set_sleep_threshold(value)


def _sleeping(env: Any) -> bool:
    return bool(env.unwrapped.tool._bodies[0].is_sleeping)


def measure_raw(env: Any, executor: Any, seed: int, frames: int,
                awake: bool) -> tuple[float, list[str], dict[str, float]]:
    """(a) frames/s of bare ``scene.step()`` with the hand holding the hammer."""
    held = reach_held_state(env, executor, seed)
    checks = [held_status(env, held)]
    step = env.unwrapped.scene.step
    with _NoSleep(env, awake):
        t0 = time.perf_counter()
        for _ in range(frames):
            step()
        dt = time.perf_counter() - t0
        asleep = _sleeping(env)
    checks.append(held_status(env, held))
    return frames / dt, _check_lines("a" if awake else "a'", checks, asleep), {}


def measure_env_step(env: Any, executor: Any, seed: int, frames: int,
                     awake: bool) -> tuple[float, list[str], dict[str, float]]:
    """(c) physics frames/s of ``env.step(action)`` (pd_joint_pos, action = current drive targets),
    the held-state checks, and the physics-only frames/s and physics/wall share inside it."""
    u = env.unwrapped
    assert u.control_mode == "pd_joint_pos", u.control_mode
    held = reach_held_state(env, executor, seed)
    checks = [held_status(env, held)]
    sim_steps = int(u._sim_steps_per_control)
    action = held["target"].astype(np.float32)
    n_steps = max(1, frames // sim_steps)
    scene = u.scene
    real_step = scene.step
    physics = 0.0

    def timed_step() -> None:  # times the scene.step() calls made inside env.step (like the executor does)
        nonlocal physics
        ts = time.perf_counter()
        real_step()
        physics += time.perf_counter() - ts

    scene.step = timed_step
    try:
        with _NoSleep(env, awake):
            t0 = time.perf_counter()
            for _ in range(n_steps):
                env.step(action)
            dt = time.perf_counter() - t0
            asleep = _sleeping(env)
    finally:
        del scene.step
    checks.append(held_status(env, held))
    n = n_steps * sim_steps
    extra = {"c_phys": n / physics, "c_ratio": physics / dt}
    return n / dt, _check_lines("c" if awake else "c'", checks, asleep), extra


def measure_executor(executor: Any, seed: int) -> dict[str, float]:
    """(b) one full expert episode: loop fps, run() fps excl. reset, physics-only fps, physics/wall, success."""
    executor.env.reset(seed=int(seed))
    t0 = time.perf_counter()
    result = executor.run(EXPERT, seed=None)
    dt = time.perf_counter() - t0
    n = executor.config.n_frames
    return {"b": result.fps, "b_run": n / dt, "b_phys": n / result.physics_time_s,
            "ratio_in": result.physics_time_s / result.wall_time_s, "ok": float(result.success)}


def _check_lines(tag: str, checks: list[tuple[bool, str]], asleep: bool) -> list[str]:
    (ok0, s0), (ok1, s1) = checks
    line = (f"({tag}) held before: {'yes' if ok0 else 'NO'} ({s0}); after: {'yes' if ok1 else 'NO'} ({s1}); "
            f"tool {'asleep' if asleep else 'awake'} at the end")
    return [line]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5, help="interleaved a/b/c rounds (one seed each)")
    parser.add_argument("--frames", type=int, default=750, help="physics frames per (a) / (c) measurement")
    parser.add_argument("--frames-asleep", type=int, default=750, help="frames per (a') / (c') measurement")
    parser.add_argument("--seed", type=int, default=1, help="first seed of the measured rounds")
    parser.add_argument("--verbose", action="store_true", help="print every measurement")
    args = parser.parse_args(argv)

    t_start = time.perf_counter()
    import envs.agents  # noqa: F401  (registers prl_hand)
    from envs.execution import ExecutorConfig
    from envs.executor import PlanExecutor
    from envs.tasks import make_env

    env = make_env("hammer", control_mode="pd_joint_pos")
    executor = PlanExecutor(env, ExecutorConfig())
    u = env.unwrapped
    steps = int(u._sim_steps_per_control)
    print(f"hammer scene, expert plan {list(EXPERT)}: {executor.plb.describe(executor.validate(EXPERT))}")
    print(f"PhysX CPU, {u.sim_freq} Hz physics, {u._sim_steps_per_control} frames per env.step; "
          f"{executor.config.n_frames} frames per episode, record every {executor.config.record_every}")

    # warm-up (excluded): the first episode pays one-off imports (pytorch-kinematics); warm (a), (c) once
    measure_executor(executor, seed=0)
    measure_raw(env, executor, 0, 200, awake=True)
    measure_env_step(env, executor, 0, 200, awake=True)

    kinds = ("a", "b", "c", "a'", "c'")
    res: dict[str, list[float]] = {k: [] for k in ("a", "a'", "b", "b_run", "b_phys", "ratio_in", "ok", "c", "c_phys", "c_ratio", "c'")}
    held_lines: list[str] = []
    for r in range(args.rounds):
        seed = args.seed + r
        shift = r % len(kinds)
        for tag in kinds[shift:] + kinds[:shift]:  # rotating order: each path runs early and late
            if tag == "b":
                for key, value in measure_executor(executor, seed).items():
                    res[key].append(value)
            else:
                measure = measure_raw if tag.startswith("a") else measure_env_step
                frames = args.frames if "'" not in tag else args.frames_asleep
                fps, lines, extra = measure(env, executor, seed, frames, awake="'" not in tag)
                res[tag].append(fps)
                if tag == "c":
                    for key, value in extra.items():
                        res[key].append(value)
                held_lines += [f"seed {seed} {line}" for line in lines]
            if args.verbose:
                print(f"  round {r} seed {seed} ({tag}): {res[tag][-1]:.0f} frames/s")
    env.close()

    med = {key: float(np.median(v)) for key, v in res.items()}
    n_bad = sum("NO" in line for line in held_lines)
    print(f"held state = end of the lift stage ({_lift_end_frame(executor)} executor frames); checked before and "
          f"after each of the {len(held_lines)} (a)/(c) measurements: "
          f"{'held in all' if not n_bad else f'NOT held in {n_bad}'}")
    for line in held_lines[:4] + [line for line in held_lines[4:] if "NO" in line]:
        print("  " + line)
    print(f"expert episodes (b) successful: {int(sum(res['ok']))}/{len(res['ok'])}")
    print()
    print(f"{'frames/s, hammer scene, hand holding the hammer':<60} {'median':>7} {'min':>7} {'max':>7}  n")
    rows = (
        ("a", "(a)  raw scene.step(), held, bodies kept awake  [limit]"),
        ("b", "(b)  PlanExecutor full episode loop, incl. recording"),
        ("b_run", "     PlanExecutor.run() call (excl. reset)"),
        ("b_phys", "     scene.step() share inside (b) (n / physics_time_s)"),
        ("c", "(c)  env.step(pd_joint_pos), held, awake, per frame"),
        ("c_phys", "     scene.step() share inside (c)"),
        ("a'", "(a') raw scene.step(), held, PhysX sleeping allowed"),
        ("c'", "(c') env.step(pd_joint_pos), held, sleeping allowed"),
    )
    for key, label in rows:
        v = res[key]
        print(f"{label:<60} {med[key]:>7.0f} {min(v):>7.0f} {max(v):>7.0f}  {len(v)}")
    print()
    print(f"b/a  executor / raw physics (awake held scene)  = {med['b'] / med['a']:.2f}   (target >= 0.5)")
    print(f"b/c  executor / ManiSkill env.step (awake)      = {med['b'] / med['c']:.1f}x")
    print(f"executor in-episode physics_time_s / wall_time_s (median) = {med['ratio_in']:.2f}; "
          f"same for env.step: {med['c_ratio']:.2f}")
    over_b = np.median(1e6 / np.asarray(res["b"]) - 1e6 / np.asarray(res["b_phys"]))
    over_c = np.median(1e6 / np.asarray(res["c"]) - 1e6 / np.asarray(res["c_phys"]))
    print(f"non-physics cost per physics frame: executor {over_b:.0f} us (targets, recording, sensors, planning), "
          f"env.step {over_c:.0f} us (controller, obs, info, reward; per env.step of {steps} frames: "
          f"{steps * over_c:.0f} us)")
    a_sleep, c_sleep = med["a'"], med["c'"]
    print(f"for reference, with PhysX sleeping allowed: b/a' = {med['b'] / a_sleep:.2f}, b/c' = {med['b'] / c_sleep:.1f}x; "
          f"a motionless held hammer falls asleep in PhysX, so a' times mostly skipped solver work")
    rss = _peak_rss_gb()
    print(f"peak RSS {rss:.2f} GB vs budget {RSS_BUDGET_GB} GB: {'within' if rss <= RSS_BUDGET_GB else 'OVER'}")
    print(f"total bench time {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
