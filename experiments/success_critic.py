"""Train the success critic (``experiments.success_critic_model``) on a task's synthesis attempts and run the RN's
plans re-ranked by it. An experiment, not a pipeline stage: no flow calls it (``experiments/README.md``).

``python -m experiments.success_critic --synthesis-dir <output-dir>/synthesis/<key> --task hammer_mixed --rn-path
<output-dir>/models/rn-seed0.pt [--scenes 50] [--top-k 20]`` computes x of every attempt of the task (the
failures' by resetting and observing their scenes, ``experiments.attempt_features``; cached beside the critic),
trains the critic on them with a fifth of the scenes held out, saves it, and runs on the RN evaluation's unseen
scenes (``envs.trials.eval_scene_seeds``): the RN's argmax (``rn``), its library plan (``rn_library``), the
library plan of its ``top_k`` the critic rates highest (``rn_critic``) and the library plan the critic alone rates
highest (``critic``). On a mixed variant each row is also split by the scenes' families (read from the scene for
the table only; no policy reads them).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from experiments.success_critic_model import CriticConfig
from flows.evaluate_rn import find_pointnet
from prl.atomic import atomic_file
from prl.stats import format_rate

#: The plans run, in order: the RN's two decodings without the critic, then the two with it.
KINDS: tuple[str, ...] = ("rn", "rn_library", "rn_critic", "critic")


def attempts_of(synthesis_dir: Path, task: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seeds (N,), plans (N, n) and successes (N,) of the task's attempts that ran (rows with an error left out);
    FileNotFoundError naming a directory without the task's attempt logs."""
    from envs.synthesis import task_attempts  # heavy: loads the simulator

    rows = [r for r in task_attempts(synthesis_dir, task) if "error" not in r]
    if not rows:
        raise FileNotFoundError(f"no attempts of task {task!r} under {synthesis_dir} "
                                f"(expected {synthesis_dir}/{task}/shard*/attempts.jsonl)")
    return (np.array([r["seed"] for r in rows], dtype=np.int64), np.array([r["plan"] for r in rows], dtype=np.int64),
            np.array([bool(r["success"]) for r in rows]))


def cached_features(path: Path, task: str, seeds: np.ndarray, pointnet_path: Path, n_points: int) -> np.ndarray:
    """x of the scenes of ``seeds``: read from ``path`` when it was computed for the same seeds, PointNet, point
    count and code of the task's scenes (``prl.version.outcome_version``), else computed
    (``experiments.attempt_features``) and written there."""
    from experiments.attempt_features import attempt_features  # heavy: loads the simulator
    from prl.pointnet import load_pointnet
    from prl.version import file_digest, outcome_version

    key = hashlib.sha256(f"{task}/{outcome_version(task)}/{file_digest(pointnet_path)}/{n_points}/".encode()
                         + seeds.tobytes()).hexdigest()
    if path.is_file():
        with np.load(path) as data:
            if str(data["key"]) == key:
                return data["x"]
    x, _ = attempt_features(task, seeds.tolist(), load_pointnet(pointnet_path), n_points)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path, "wb") as fh:
        np.savez(fh, x=x, key=np.array(key))
    return x


def critic_policy(model: Any, critic: Any, pointnet: Any, task: str, seeds: list[int], n_points: int,
                  top_k: int | None):
    """An ``envs.trials.Policy``: the critic's choice among the RN's ``top_k`` library plans (all of them when
    None) for the live scene."""
    from experiments.success_critic_model import critic_plan
    from prl.features import scene_features  # heavy: trimesh
    from prl.plb import load_plb
    from prl.rn_decode import predict_proba

    texts = list(load_plb().texts(task))
    library = model.plan_libraries[task]

    def choose(i: int, env: Any, x_manip: np.ndarray) -> list[int]:
        x = scene_features(task, int(seeds[i]), dict(env.scene_params), x_manip, texts[i % len(texts)], pointnet,
                           n_points)
        probs = predict_proba(model, x) if top_k is not None else None
        return critic_plan(critic, x, library, probs, top_k)[0].tolist()

    return choose


def table_row(name: str, outcomes: list[Any], families: dict[int, int]) -> str:
    """Successes with the Wilson interval, per family, and the three most frequent plans."""
    fam = [families.get(i, -1) for i in range(len(outcomes))]
    parts = [f"{name:<11} {format_rate(sum(o.success for o in outcomes), len(outcomes))}"]
    for f in sorted(set(fam)):
        idx = [i for i, g in enumerate(fam) if g == f]
        parts.append(f"family {f}: {sum(outcomes[i].success for i in idx)}/{len(idx)}")
    common = Counter(tuple(o.plan) for o in outcomes).most_common(3)
    return "; ".join(parts) + " | plans " + ", ".join(f"{list(p)} x{c}" for p, c in common)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.success_critic", description=__doc__.split("\n\n")[0])
    parser.add_argument("--synthesis-dir", required=True, type=Path,
                        help="the run's synthesis directory, <output-dir>/synthesis/<key> (holds <task>/shard*/)")
    parser.add_argument("--task", required=True)
    parser.add_argument("--rn-path", required=True, type=Path, help="RN checkpoint whose plan library is ranked")
    parser.add_argument("--pointnet-path", type=Path, default=None, help="default: the one beside the RN")
    parser.add_argument("--out-dir", type=Path, default=None, help="where the critic and the cached x go "
                                                                   "(default: beside the RN)")
    parser.add_argument("--scenes", type=int, default=50, help="unseen scenes of the RN evaluation")
    parser.add_argument("--seed", type=int, default=0, help="run seed of those scenes and of the critic")
    parser.add_argument("--top-k", type=int, default=20, help="the RN's best library plans the critic chooses among")
    parser.add_argument("--epochs", type=int, default=CriticConfig.epochs)
    parser.add_argument("--kinds", default=",".join(KINDS), help=f"plans run, of {','.join(KINDS)}")
    args = parser.parse_args(argv)
    kinds = [k for k in args.kinds.split(",") if k]
    bad = [k for k in kinds if k not in KINDS]
    if bad or args.scenes < 1 or args.top_k < 1:
        parser.error(f"--kinds must be of {KINDS} (got {bad}); --scenes and --top-k >= 1")
    try:
        pn_path = find_pointnet(args.rn_path, args.pointnet_path)
        seeds, plans, success = attempts_of(args.synthesis_dir, args.task)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    from envs.trials import eval_scene_seeds, run_policy  # heavy: loads the simulator
    from experiments.success_critic_model import save_critic, train_critic
    from prl.features import split_by_seed
    from prl.plb import load_plb
    from prl.pointnet import load_pointnet
    from prl.rn_checkpoint import load_rn
    from prl.rn_policy import rn_policy

    model = load_rn(args.rn_path)
    if args.task not in model.plan_libraries:
        print(f"error: the RN has no plan library for task {args.task!r}", file=sys.stderr)
        return 2
    pointnet = load_pointnet(pn_path)
    n_points = pointnet.cfg.n_points
    out_dir = args.out_dir or args.rn_path.parent
    x = cached_features(out_dir / f"critic-x-{args.task}.npz", args.task, seeds, pn_path, n_points)
    train, val = split_by_seed(seeds, 0.2, salt=args.seed)
    print(f"{args.task}: {len(seeds)} attempts, {int(success.sum())} successes; critic on {len(train)}, "
          f"held out {len(val)}")
    critic, history = train_critic(x[train], plans[train], success[train],
                                   CriticConfig(epochs=args.epochs, seed=args.seed),
                                   x[val], plans[val], success[val])
    best = min(history, key=lambda r: r["critic/val_loss"])
    print("held out: " + ", ".join(f"{k.split('/')[1]} {v:.3f}" for k, v in best.items()))
    path = save_critic(critic, out_dir / f"critic-{args.task}.pt",
                       {"task": args.task, "attempts": len(seeds), "pointnet": pn_path.name, **best})
    print(f"critic written to {path}")
    eval_seeds = eval_scene_seeds(args.seed, args.scenes)
    families: dict[int, int] = {}
    results = {}
    for kind in kinds:
        if kind in ("rn", "rn_library"):
            inner = rn_policy(model, pointnet, args.task, list(load_plb().texts(args.task)), eval_seeds, n_points,
                              kind)
        else:
            inner = critic_policy(model, critic, pointnet, args.task, eval_seeds, n_points,
                                  args.top_k if kind == "rn_critic" else None)

        def policy(i, env, x_manip, inner=inner):  # the scene's family, for the table only
            families[i] = int(env.scene_params.get("family", -1))
            return inner(i, env, x_manip)

        results[kind] = run_policy(args.task, policy, eval_seeds, desc=f"{args.task} {kind} plans")
        print(table_row(kind, results[kind], families), flush=True)
    summary = {k: [int(o.success) for o in v] for k, v in results.items()}
    with atomic_file(out_dir / f"critic-eval-{args.task}-seed{args.seed}.json", "w") as fh:
        json.dump({"task": args.task, "top_k": args.top_k, "seeds": eval_seeds, "families": families,
                   "success": summary, "held_out": best}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
