"""A red team for the tasks' success rules: ``python -m envs.red_team --tasks hammer,sweep --out docs/red_team_search.md``.

A search that is not the expert looks for plans that succeed, and what it finds is shown next to the evidence of
how it succeeded. Per task, the cross-entropy method (``prl.cem``) starts from uniform plans: each round draws
``--per-round`` plans, runs each once on a fresh scene (seeds no other part of the project uses), and moves the
per-dimension categoricals towards the top quarter by score (success first, then the task's measure), with a
floor of 0.1 x uniform. Then the most often successful distinct plans are run again on ``--check-scenes`` fresh
scenes each, and every success is listed with the outcome's evidence fields (``evidence``, declared by each task's class): what the hand did to
the nail, how far closing the grasp turned the cap, whether the hand touched the cube. ``--pictures DIR`` renders
the stages of each task's most successful plan.

``--rl-timesteps N`` adds the second searcher: the LN with no demonstrations (pure RL, K = 0: A2C over the
Representation Space with the paper's settings, ``prl.config.LNConfig``) trained for N plan episodes per task on
the plan environment, x standardised with the statistics of 32 scenes' observations (no dataset is needed),
PointNet features from a quick-profile PointNet trained once and kept in ``outputs/models``. Its final
deterministic plan is run on ``--check-scenes`` fresh scenes, each success with its evidence.
"""

from __future__ import annotations

import argparse
import datetime
import sys
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from envs.plan_env import PlanEnv
from envs.tasks import TASK_ENV_IDS, fast_resets, task_class
from envs.trials import run_policy, run_trials
from envs.vec_env import make_vec_env
from prl import cem
from prl.config import LNConfig
from prl.constants import REPO_ROOT
from prl.plb import load_plb
from prl.pointnet import load_pointnet, pointnet_config, save_pointnet, train_pointnet
from prl.version import code_version


def evidence(task: str) -> tuple[str, ...]:
    """Outcome fields shown with each success of ``task``: the measure and how it came about (its class's
    ``evidence``, a variant's inherited from its task)."""
    return tuple(task_class(task).evidence)


def red_team_seed(task: str, stage: str, i: int) -> int:
    """A scene seed of the red team (a hash: it meets the trial, evaluation and LN seeds only by chance)."""
    return zlib.crc32(f"red-team/{task}/{stage}/{i}".encode())


@dataclass
class SearchResult:
    """One task's search: every attempt, the rounds' success rates and the re-run top plans."""

    task: str
    attempts: list[dict[str, Any]] = field(default_factory=list)
    round_rates: list[float] = field(default_factory=list)
    top: list[dict[str, Any]] = field(default_factory=list)
    final_probs: list[np.ndarray] = field(default_factory=list)


def _rows(task: str, outcomes: list[Any]) -> list[dict[str, Any]]:
    """The attempts of ``envs.trials`` outcomes as report rows, with their ``evidence`` fields."""
    keys = evidence(task)
    return [{"plan": list(o.plan), "seed": o.seed, "success": o.success, "measure": o.measure, "fault": o.fault,
             "error": o.error, "evidence": {k: o.outcome[k] for k in keys if k in o.outcome}} for o in outcomes]


def search(task: str, rounds: int = 5, per_round: int = 32, top_k: int = 5, check_scenes: int = 10,
           elite: float = 0.25, seed: int = 0) -> SearchResult:
    """The cross-entropy search on ``task`` and the re-run of its top plans (module docstring)."""
    plb = load_plb()
    rng = np.random.default_rng(zlib.crc32(f"red-team/{task}/{seed}".encode()))
    probs = cem.uniform(plb.sizes)
    out = SearchResult(task)
    for r in range(rounds):
        plans = cem.sample(probs, per_round, rng)
        seeds = [red_team_seed(task, f"s{seed}r{r}", i) for i in range(per_round)]
        rows = _rows(task, run_trials(task, plans.tolist(), seeds, progress=False))
        out.attempts += rows
        out.round_rates.append(float(np.mean([row["success"] for row in rows])))
        scores = np.array([1000.0 * row["success"] + row["measure"] for row in rows])
        probs = cem.update(probs, cem.elites(plans, scores, elite), smoothing=0.7, floor=0.1)
        print(f"{task} round {r}: {sum(row['success'] for row in rows)}/{per_round} successes", flush=True)
    out.final_probs = probs
    wins = Counter(tuple(row["plan"]) for row in out.attempts if row["success"])
    for k, (plan, n_found) in enumerate(wins.most_common(top_k)):
        seeds = [red_team_seed(task, f"s{seed}check{k}", i) for i in range(check_scenes)]
        rows = _rows(task, run_trials(task, [plan] * check_scenes, seeds, progress=False))
        out.top.append({"plan": list(plan), "found": n_found, "checks": rows,
                        "rate": float(np.mean([row["success"] for row in rows]))})
    return out


def quick_pointnet(path: Path = REPO_ROOT / "outputs" / "models" / "red-team-pointnet.pt") -> Path:
    """A quick-profile PointNet for the RL searcher, trained once (about a CPU-minute) and reused."""
    if not path.is_file():
        cfg = pointnet_config("quick")
        model, _ = train_pointnet(cfg)
        save_pointnet(model, cfg, path)
    return path


def rl_search(task: str, timesteps: int, check_scenes: int = 10, seed: int = 0, n_envs: int = 2) -> dict[str, Any]:
    """Pure RL (K = 0) on ``task`` for ``timesteps`` plan episodes; its final plan on fresh scenes with evidence."""
    from prl.ln import ln_policy, make_ln, train_ln  # heavy: torch (stable-baselines3), only the RL searcher

    pointnet = quick_pointnet()
    probe = PlanEnv(task, pointnet, run_seed=seed + 1000)
    try:
        xs = np.stack([probe.reset()[0] for _ in range(32)])
    finally:
        probe.close()
    cfg = LNConfig(timesteps=timesteps, n_envs=n_envs, demo_steps=0, seed=seed)
    env = make_vec_env(PlanEnv, task, n_envs, run_seed=seed, pointnet_path=pointnet)
    try:
        model = make_ln(env, cfg, xs.mean(axis=0), xs.std(axis=0))
        with fast_resets():
            rows = train_ln(model, timesteps, progress=False, desc=f"{task} pure RL")
    finally:
        env.close()
    seeds = [red_team_seed(task, f"s{seed}rl", i) for i in range(check_scenes)]
    policy = ln_policy(model.policy, load_pointnet(pointnet), task, load_plb().texts(task), seeds, 512)
    checks = _rows(task, run_policy(task, policy, seeds, progress=False))
    return {"task": task, "timesteps": timesteps, "curve": [r.get("success_rate", 0.0) for r in rows],
            "checks": checks}


def _fmt(value: Any) -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.2f}"
    return str(value)


def report(results: list[SearchResult], command: str, rl: list[dict[str, Any]] = ()) -> str:
    """The searches as markdown: per task the rounds, the top plans' rates and every checked success's evidence."""
    plb = load_plb()
    lines = ["# Red-team search", "",
             (f"*Made by `{command}` on {datetime.date.today().isoformat()}, code {code_version()}.* "
              "What the search found is judged in [guide/red_team.md](guide/red_team.md)."), ""]
    for res in results:
        expert = list(task_class(res.task).expert_plan)
        lines += [f"## {res.task}", "",
                  (f"Success rate per round (uniform plans first): {', '.join(f'{r:.2f}' for r in res.round_rates)}; "
                   f"{sum(a['success'] for a in res.attempts)} successes in {len(res.attempts)} attempts. "
                   f"Most probable plan at the end: `{[int(np.argmax(p)) for p in res.final_probs]}` "
                   f"(expert `{expert}`)."), "",
                  "| plan | choices | found | re-run successes | evidence of the successes (mean) |", "|---|---|---|---|---|"]
        for top in res.top:
            ok = [row for row in top["checks"] if row["success"]]
            keys = evidence(res.task)
            ev = "; ".join(f"{k} {_fmt(float(np.mean([float(r['evidence'][k]) for r in ok])))}" for k in keys) if ok else "-"
            names = ", ".join(str(c) for c in plb.decode(top["plan"]))
            lines.append(f"| `{top['plan']}` | {names} | {top['found']} | {len(ok)}/{len(top['checks'])} | {ev} |")
        lines.append("")
    for res in rl:
        keys = evidence(res["task"])
        ok = [row for row in res["checks"] if row["success"]]
        lines += [f"## {res['task']}: pure RL (K = 0), {res['timesteps']} timesteps", "",
                  (f"Training success per update: {', '.join(f'{r:.2f}' for r in res['curve'])}. The final plan on "
                   f"{len(res['checks'])} fresh scenes: {len(ok)} successes."), "",
                  "| plan | scenes | successes | evidence of the successes (mean) |", "|---|---|---|---|"]
        for plan, rows in sorted(_by_plan(res["checks"]).items(), key=lambda kv: -len(kv[1])):
            good = [r for r in rows if r["success"]]
            ev = "; ".join(f"{k} {_fmt(float(np.mean([float(r['evidence'][k]) for r in good])))}" for k in keys) if good else "-"
            lines.append(f"| `{list(plan)}` | {len(rows)} | {len(good)} | {ev} |")
        lines.append("")
    return "\n".join(lines)


def _by_plan(rows: list[dict[str, Any]]) -> dict[tuple[int, ...], list[dict[str, Any]]]:
    out: dict[tuple[int, ...], list[dict[str, Any]]] = {}
    for row in rows:
        out.setdefault(tuple(row["plan"]), []).append(row)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default=",".join(TASK_ENV_IDS))
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--per-round", type=int, default=32)
    parser.add_argument("--top", type=int, default=5, help="distinct successful plans re-run")
    parser.add_argument("--check-scenes", type=int, default=10, help="fresh scenes per re-run plan")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=None, help="write the markdown report here")
    parser.add_argument("--pictures", default=None, help="render the stages of each task's top plan into this folder")
    parser.add_argument("--rl-timesteps", type=int, default=0, help="also search with pure RL for this many timesteps")
    parser.add_argument("--no-cem", action="store_true", help="skip the cross-entropy search (with --rl-timesteps)")
    args = parser.parse_args(argv)
    tasks = [t.strip() for t in args.tasks.split(",") if t.strip()]
    bad = [t for t in tasks if t not in TASK_ENV_IDS]
    if bad or not tasks:
        parser.error(f"unknown task(s) {bad or '(none given)'}; known: {', '.join(TASK_ENV_IDS)}")
    for name in ("rounds", "per_round", "top", "check_scenes"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.rl_timesteps < 0:
        parser.error(f"--rl-timesteps must be >= 0, got {args.rl_timesteps}")
    results = [] if args.no_cem else \
        [search(t, args.rounds, args.per_round, args.top, args.check_scenes, seed=args.seed) for t in tasks]
    rl = [rl_search(t, args.rl_timesteps, args.check_scenes, args.seed) for t in tasks] if args.rl_timesteps else []
    text = report(results, "python -m envs.red_team " + " ".join(argv if argv is not None else sys.argv[1:]), rl)
    if args.out:
        Path(args.out).write_text(text)
    print(text)
    if args.pictures:
        from envs.render_stages import render_stage_pictures  # optional: needs a Vulkan device

        for res in results:
            if res.top:
                best = max(res.top, key=lambda t: t["rate"])
                pictures = render_stage_pictures(res.task, best["plan"], best["checks"][0]["seed"],
                                                 Path(args.pictures) / res.task)
                print(pictures.sheet)
    return 0


if __name__ == "__main__":
    sys.exit(main())
