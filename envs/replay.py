"""Replay an exported dataset's ``action`` stream open-loop in the task's joint-control environment, as
``lerobot-replay`` sends a dataset episode to a robot: does each episode reproduce its recorded outcome?

For each chosen episode: the task's scene is rebuilt from the episode's scene seed (``meta/prl_scenes.jsonl``), the
joint-control environment (``envs.joint_env``, the dataset's 50 Hz) runs the observation phase and the plan's first
frame, then each row's ``action`` is the target of one step (reached at its end), the task being told of each
recorded stage as it starts (a measure that counts from a stage, the unscrew's turn, counts as when the demo was
recorded). Reported per episode: the task's success and measure at the end against the recorded ones, and the
largest joint-position deviation from the recorded ``observation.state`` (the replay's state after step k against
the recorded row k + 1, the same physics frame: ``prl.export_schema.replay_actions``).

    prl-replay --dataset-root outputs/datasets/hammer-seed0 --episodes-per-task 50 --out docs/replay.md
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from prl.constants import N_JOINTS
from prl.export_schema import FEATURES, read_scenes, replay_actions
from prl.stages import STAGES


@dataclass(frozen=True)
class ReplayOutcome:
    """One episode replayed."""

    episode_index: int
    task: str
    seed: int
    recorded_success: bool
    success: bool
    recorded_measure: float
    measure: float
    max_joint_deviation: float
    """Largest |qpos - recorded qpos| over the episode's rows and joints (m for the arm's slides, rad otherwise)."""
    error: str = ""

    @property
    def reproduced(self) -> bool:
        """The replay's success equals the recorded one."""
        return self.success == self.recorded_success and not self.error


def episode_columns(root: Path | str, names: Sequence[str] = ("action", "observation.state", "stage")
                    ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """``({feature: (N, width) array}, episode starts (E + 1,))`` of an exported dataset, read with lerobot's
    ``LeRobotDataset`` offline. ExportError (``prl.export_check``) when ``root`` is no complete dataset."""
    from prl.export_check import load_local  # heavy: lerobot

    ds = load_local(Path(root))
    table = ds.hf_dataset.data
    n = table.num_rows
    cols = {}
    for name in names:
        col = table.column(name).combine_chunks()
        cols[name] = (col.flatten() if hasattr(col, "flatten") else col).to_numpy().reshape(n, -1)
    lengths = np.asarray(ds.meta.episodes["length"], dtype=np.int64)
    return cols, np.concatenate([[0], np.cumsum(lengths)])


def replay_transitions(env: Any, seed: int, actions: np.ndarray, stages: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """``actions`` (T, 30 joint targets), one a step, replayed open loop in ``env`` (a ``JointControlEnv`` with T
    steps) on the scene of ``seed``: the observations (T + 1: the reset's, then one after each step), the rewards
    (T) and the last step's info. ``stages`` (T,) tells the task of each recorded stage as it starts, as when the
    demo was recorded; None: none, as in the environment's own episodes. RuntimeError naming a step's error."""
    first, _ = env.reset(options={"scene_seed": int(seed)})
    observations, rewards, info, last_stage = [first], [], {}, -1
    for k in range(len(actions)):
        if stages is not None and int(stages[k]) != last_stage:
            last_stage = int(stages[k])
            env.on_stage_start(STAGES[last_stage])
        obs, reward, done, _, info = env.step_target(actions[k])
        observations.append(obs)
        rewards.append(reward)
        if done:
            break
    if info.get("error"):
        raise RuntimeError(info["error"])
    return np.asarray(observations), np.asarray(rewards, np.float64), info


def replay_episode(env: Any, seed: int, actions: np.ndarray, states: np.ndarray, stages: np.ndarray
                   ) -> tuple[bool, float, float]:
    """(success, measure, largest joint deviation) of ``actions`` (T, 30), one a step, on the scene of
    ``seed`` in ``env`` (a ``JointControlEnv`` with T steps), against the recorded ``states`` (T, 60): the state
    after step k against the recorded row k + 1."""
    observations, _, info = replay_transitions(env, seed, actions, stages)
    n = min(len(observations), len(states))
    deviation = float(np.max(np.abs(observations[1:n, :N_JOINTS] - states[1:n, :N_JOINTS]))) if n > 1 else 0.0
    return bool(info["success"]), float(info["measure"]), deviation


def replayed_demonstrations(root: Path | str, task: str, episodes: Sequence[int], gamma: float,
                            progress: bool = False) -> Any:
    """``prl.joint_bc.JointDemonstrations`` of ``episodes`` (indices of the dataset at ``root``, all of ``task``):
    each episode's ``action`` rows replayed open loop in the task's joint-control environment on its scene, with
    no stage announced (as the environment's own episodes), giving the observation before each step, the action
    that step's target maps from and the discounted return from the step on (``gamma``). ValueError naming an
    episode of another task."""
    from envs.joint_env import JointControlEnv  # heavy: loads the simulator
    from prl.joint_bc import JointDemonstrations, actions_of_targets, returns_to_go

    scenes = read_scenes(root)
    other = [i for i in episodes if scenes[i]["task"] != task]
    if other:
        raise ValueError(f"episode {other[0]} of the dataset at {str(root)!r} is of task "
                         f"{scenes[other[0]]['task']!r}, not {task!r}")
    cols, starts = episode_columns(root, ("action",))
    obs, act, ret = [], [], []
    env: Any = None
    try:
        for i in tqdm(episodes, desc=f"{task} demonstrations replayed", unit="episode", disable=not progress):
            lo, hi = int(starts[i]), int(starts[i + 1])
            if env is None or env.steps != hi - lo:
                if env is not None:
                    env.close()
                env = JointControlEnv(task, steps=hi - lo)
                low, high = env.target_of(-np.ones(N_JOINTS)), env.target_of(np.ones(N_JOINTS))
            targets = cols["action"][lo:hi]
            observations, rewards, _ = replay_transitions(env, scenes[i]["seed"], targets)
            steps = len(rewards)
            obs.append(observations[:steps])
            act.append(actions_of_targets(targets[:steps], low, high))
            ret.append(returns_to_go(rewards, gamma))
    finally:
        if env is not None:
            env.close()
    return JointDemonstrations(np.concatenate(obs).astype(np.float32), np.concatenate(act).astype(np.float32),
                               np.concatenate(ret).astype(np.float32))


def demo_replays(env: Any, demo: Any) -> bool:
    """Whether a recorded demo (``prl.demo.Demo``) succeeds again when its ``action`` stream, as the export writes it
    (``prl.export_schema.replay_actions`` of its targets, rounded to the feature's float32), is replayed open loop in
    ``env`` (a ``JointControlEnv`` of the demo's length) on its scene, as ``replay_dataset`` replays an exported
    episode."""
    states = np.concatenate([np.asarray(demo.qpos), np.asarray(demo.qvel)], axis=1)
    # in the dtype the export stores them: a knife-edge episode turns on the rounding to float32
    actions = replay_actions(np.asarray(demo.target)).astype(FEATURES["action"]["dtype"])
    success, _, _ = replay_episode(env, demo.seed, actions, states, np.asarray(demo.stage).reshape(-1))
    return success


def synthesis_runs(scenes: Sequence[dict[str, Any]]) -> list[str]:
    """The synthesis runs a dataset's episodes came from, by their directory names (``seed<N>-shards<S>-frames<F>-
    <proposal>[-replayed]``, ``flows.synthesize.synthesis_dir``), read from each scene record's demo path
    ``.../<run>/<task>/shard<k>/ep<j>.npz``; sorted."""
    sources = [Path(str(s.get("source", ""))) for s in scenes]
    return sorted({p.parents[2].name for p in sources if len(p.parents) > 2})


def choose_episodes(scenes: Sequence[dict[str, Any]], per_task: int, tasks: Sequence[str] | None = None) -> list[int]:
    """The first ``per_task`` episode indices of each task (of ``tasks``, or every task of the dataset) in episode
    order. ValueError naming a task the dataset does not hold."""
    held = sorted({s["task"] for s in scenes})
    for task in tasks or ():
        if task not in held:
            raise ValueError(f"the dataset holds no {task!r} episode (it holds {', '.join(held)})")
    wanted = set(tasks or held)
    counts: dict[str, int] = {}
    chosen = []
    for s in scenes:
        if s["task"] in wanted and counts.get(s["task"], 0) < per_task:
            counts[s["task"]] = counts.get(s["task"], 0) + 1
            chosen.append(int(s["episode_index"]))
    return chosen


def replay_dataset(root: Path | str, per_task: int = 50, tasks: Sequence[str] | None = None,
                   progress: bool = True) -> list[ReplayOutcome]:
    """Replay the first ``per_task`` episodes of each task of the dataset at ``root``; one ``ReplayOutcome`` each."""
    from envs.joint_env import JointControlEnv  # heavy: loads the simulator

    scenes = read_scenes(root)
    chosen = choose_episodes(scenes, per_task, tasks)
    cols, starts = episode_columns(root)
    envs: dict[str, JointControlEnv] = {}
    out = []
    try:
        for i in tqdm(chosen, desc="replaying episodes", unit="episode", disable=not progress):
            scene, lo, hi = scenes[i], int(starts[i]), int(starts[i + 1])
            task = scene["task"]
            env = envs.get(task)
            if env is None or env.steps != hi - lo:
                if env is not None:
                    env.close()
                env = envs[task] = JointControlEnv(task, steps=hi - lo)
            recorded = scene.get("outcome") or {}
            key = env.measure_key
            try:
                success, measure, dev = replay_episode(env, scene["seed"], cols["action"][lo:hi],
                                                       cols["observation.state"][lo:hi], cols["stage"][lo:hi, 0])
                error = ""
            except Exception as exc:  # noqa: BLE001 - one episode's error is reported, not fatal
                success, measure, dev, error = False, float("nan"), float("nan"), f"{type(exc).__name__}: {exc}"
                env.close()
                envs.pop(task)
            out.append(ReplayOutcome(episode_index=i, task=task, seed=int(scene["seed"]),
                                     recorded_success=bool(recorded.get("success", False)), success=success,
                                     recorded_measure=float(recorded.get(key, float("nan"))), measure=measure,
                                     max_joint_deviation=dev, error=error))
    finally:
        for env in envs.values():
            env.close()
    return out


def replay_table(outcomes: Sequence[ReplayOutcome]) -> list[str]:
    """Markdown rows per task: episodes, reproduced (share), median and largest joint deviation."""
    lines = ["| task | episodes | reproduced | share | joint deviation, median | largest |", "|---|---|---|---|---|---|"]
    for task in sorted({o.task for o in outcomes}):
        rows = [o for o in outcomes if o.task == task]
        devs = np.array([o.max_joint_deviation for o in rows], dtype=float)
        ok = sum(o.reproduced for o in rows)
        lines.append(f"| {task} | {len(rows)} | {ok} | {ok / len(rows):.2f} | {np.nanmedian(devs):.4f} | "
                     f"{np.nanmax(devs):.4f} |")
    return lines


def _runs_text(runs: Sequence[str]) -> str:
    if not runs:
        return ""
    checked = all(r.endswith("-replayed") for r in runs)
    return (f" Its demos came from the synthesis run{'s' if len(runs) > 1 else ''} {', '.join(f'`{r}`' for r in runs)}"
            + (" (a demo kept only when its replay succeeded at synthesis, `--replay-check`)" if checked else "") + ".")


def replay_page(outcomes: Sequence[ReplayOutcome], command: str, dataset: str, runs: Sequence[str] = ()) -> str:
    """The markdown page of a replay: the command that made it, the synthesis ``runs`` the dataset came from, the
    table (``replay_table``), the pooled share and every episode that did not reproduce its recorded outcome."""
    ok = sum(o.reproduced for o in outcomes)
    lines = [f"<!-- Generated by `{command}`; do not edit by hand. -->", "# Replaying the dataset's actions", "",
             (f"Generated by `{command}` (`envs/replay.py`) on the dataset `{dataset}`: each episode's `action` rows "
             "one per 50 Hz step, open loop, in the task's joint-control environment on the episode's scene "
             "(`envs/joint_env.py`); *reproduced* is the task's success equal to the recorded one, the deviation the "
             "largest |qpos - recorded qpos| over an episode's rows and joints (rad; m for the arm's slides)."
             + _runs_text(runs)), "",
             *replay_table(outcomes), "", f"All tasks: {ok}/{len(outcomes)} = {ok / max(len(outcomes), 1):.2f}.", ""]
    missed = [o for o in outcomes if not o.reproduced]
    if missed:
        lines += ["Episodes that did not reproduce (recorded measure -> replayed measure):", ""]
        lines += [f"- {o.task} episode {o.episode_index} (scene seed {o.seed}): {o.recorded_success} "
                  f"({o.recorded_measure:.2f}) -> {o.success} ({o.measure:.2f}){' ' + o.error if o.error else ''}"
                  for o in missed]
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="prl-replay", description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset-root", required=True, type=Path, help="an exported LeRobot dataset's root")
    parser.add_argument("--episodes-per-task", type=int, default=50, help="first episodes replayed per task (50)")
    parser.add_argument("--tasks", default="", help="comma-separated tasks of the dataset (default: all)")
    parser.add_argument("--out", type=Path, default=None, help="write the page (markdown) here and every episode's "
                        "outcome as JSON beside it (same name, .json)")
    args = parser.parse_args(argv)
    if args.episodes_per_task < 1:
        parser.error(f"--episodes-per-task must be >= 1, got {args.episodes_per_task}")
    tasks = [t for t in args.tasks.split(",") if t] or None
    outcomes = replay_dataset(args.dataset_root, args.episodes_per_task, tasks)
    command = " ".join(["prl-replay", "--dataset-root", f"<{args.dataset_root.name}>", "--episodes-per-task",
                        str(args.episodes_per_task), *(["--tasks", args.tasks] if args.tasks else []),
                        *(["--out", str(args.out)] if args.out else [])])
    page = replay_page(outcomes, command, args.dataset_root.name, synthesis_runs(read_scenes(args.dataset_root)))
    print(page)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(page)
        args.out.with_suffix(".json").write_text(json.dumps([asdict(o) for o in outcomes], indent=1) + "\n")


if __name__ == "__main__":
    main()
