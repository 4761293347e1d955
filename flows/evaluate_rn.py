"""Evaluate a trained RN checkpoint in simulation on any range of unseen scenes, tracked in MLflow.

The pipeline's ``rn-eval`` stage runs its model on one fixed range of scene seeds; this flow runs a saved
checkpoint on another one (a confirmation set, more scenes, wider ranges) with the same policy code::

    python -m flows.evaluate_rn --rn-path /tmp/rnrun/models/rn-seed0.pt --first-seed 10500000 --scenes 50

The PointNet checkpoint is found beside the RN (``pointnet-*.pt`` whose SHA-256 the RN recorded), or given
with ``--pointnet-path`` (each flag is the flow's parameter of that name). Each plan kind (the RN decodings
and the 'prior' and 'expert' baselines) is logged as ``<task>/<split>/<kind>_success_rate`` with its 95%
Wilson interval, plus the per-scene outcomes.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from flows.artifacts import publish_table, rate_row
from flows.train_rn import TrainedRN
from prl import tracking
from prl.config import PipelineConfig
from prl.rn_policy import DECODINGS, check_pointnet

#: Plan kinds run next to the RN decodings on the same scenes: a plan sampled from the task prior, the expert plan.
BASELINES: tuple[str, ...] = ("prior", "expert")
#: The prior baseline's plans are seeded by the run seed plus this (the pipeline's rn-eval; ``--prior-seed``).
PRIOR_SEED_OFFSET = 31


@dataclass(frozen=True)
class RNEval:
    """Success rates keyed ``<task>/rn/<split>`` (each per plan kind) and the unseen scenes they were measured on."""

    rates: dict[str, dict[str, float]]
    eval_seeds: tuple[int, ...]


@task(name="rn-eval-sim", task_run_name="rn-eval-{task_name}-x{randomization}", cache_policy=NO_CACHE)
def evaluate_in_sim(rn_path: Path, pointnet_path: Path, task_name: str, seeds: list[int], n_points: int,
                    n_frames: int, randomization: float, prior_seed: int,
                    decodings: tuple[str, ...] = DECODINGS) -> dict[str, list]:
    """On each of ``seeds``' scenes execute the RN's plan under each of ``decodings`` and two baselines: a
    plan sampled from the task prior the demos were drawn from ('prior') and the task's hand-written
    expert plan, the same on every scene ('expert'); the outcomes of each, keyed by decoding or baseline."""
    return {**rn_outcomes(rn_path, pointnet_path, task_name, seeds, n_points, n_frames, randomization, decodings),
            **baseline_outcomes(task_name, seeds, n_frames, randomization, prior_seed)}


def rn_outcomes(rn_path: Path, pointnet_path: Path, task_name: str, seeds: list[int], n_points: int, n_frames: int,
                randomization: float, decodings: tuple[str, ...] = DECODINGS) -> dict[str, list]:
    """On each of ``seeds``' scenes execute the RN's plan under each of ``decodings``; the outcomes of each
    (``envs.trials.TrialOutcome``), keyed by decoding. ValueError when the PointNet is not the RN's."""
    from envs.trials import run_policy  # heavy: loads the simulator
    from prl.plb import load_plb
    from prl.pointnet import load_pointnet
    from prl.rn_checkpoint import load_rn
    from prl.rn_policy import rn_policy

    model = load_rn(rn_path)
    check_pointnet(model, pointnet_path)
    texts = list(load_plb().texts(task_name))
    pointnet = load_pointnet(pointnet_path)
    out: dict[str, list] = {}
    for kind in decodings:
        policy = rn_policy(model, pointnet, task_name, texts, seeds, n_points, kind)
        out[kind] = run_policy(task_name, policy, seeds, n_frames=n_frames, randomization=randomization,
                               desc=f"{task_name} {kind} plans (x{randomization:g} ranges)")
    return out


def baseline_outcomes(task_name: str, seeds: list[int], n_frames: int, randomization: float,
                      prior_seed: int) -> dict[str, list]:
    """On each of ``seeds``' scenes execute the ``BASELINES``: a plan sampled from the task prior per scene
    (``envs.trials.plan_set`` seeded ``prior_seed``) and the task's expert plan; on a mixed variant also the family
    oracle and each family's expert (``envs.families.family_outcomes``); the outcomes of each, by kind."""
    from envs.families import family_outcomes  # heavy: loads the simulator
    from envs.tasks import task_class
    from envs.trials import plan_set, run_trials

    out = {kind: run_trials(task_name, plan_set(task_name, kind, len(seeds), plan_seed), seeds, n_frames=n_frames,
                            randomization=randomization)
           for kind, plan_seed in zip(BASELINES, (prior_seed, 0), strict=True)}
    ran = {tuple(task_class(task_name).expert_plan): out["expert"]}  # family 0's plan: not run twice
    return {**out, **family_outcomes(task_name, seeds, n_frames, randomization, ran)}


@task(name="rn-eval", cache_policy=NO_CACHE)
def rn_eval_stage(cfg: PipelineConfig, rn: TrainedRN, tasks: tuple[str, ...]) -> RNEval:
    """Execute the RN's plans (each decoding) and the baselines on ``cfg.rn_eval_scenes`` unseen scenes per task,
    once with the training ranges and once with them scaled by ``cfg.wide_randomization``; log each."""
    from envs.trials import eval_scene_seeds  # heavy: loads the simulator

    seeds = eval_scene_seeds(cfg.seed, cfg.rn_eval_scenes)
    rates: dict[str, dict[str, float]] = {}
    rows = []
    with tracking.child_run("rn-eval", params={"scenes_per_split": cfg.rn_eval_scenes,
                                               "wide_randomization": cfg.wide_randomization}):
        for split, scale in (("train_ranges", 1.0), ("wide_ranges", cfg.wide_randomization)):
            for name in tasks:
                out = evaluate_in_sim(rn.rn_path, rn.pointnet_path, name, seeds, cfg.n_points, cfg.episode_frames,
                                      scale, cfg.seed + PRIOR_SEED_OFFSET)
                print(f"{name} ({split}): plans executed on {len(seeds)} unseen scenes")
                rates[f"{name}/rn/{split}"] = log_rn_eval(name, split, out)
                rows += [rate_row(sum(bool(o.success) for o in outs), len(outs), task=name, split=split, plan=kind)
                         for kind, outs in out.items()]
    publish_table("rn-success", rows, f"The RN's plans (three decodings) and two baselines on {len(seeds)} unseen "
                  f"scenes per task: training ranges, and ranges x{cfg.wide_randomization:g} (wide_ranges)")
    return RNEval(rates, tuple(seeds))


def log_rn_eval(task: str, split: str, out: dict[str, list]) -> dict[str, float]:
    """Log one evaluation's outcomes (``evaluate_in_sim``'s result) to the active MLflow run and print them;
    return the success rate per plan kind. On a mixed variant (an ``oracle`` kind is there) each kind's successes
    per scene family are logged and printed too (``<task>/<split>/<kind>_family<k>_success_rate``)."""
    import mlflow  # heavy: mlflow

    from envs.families import families_of_oracle, per_family
    from prl.stats import format_rate, wilson_interval

    families = families_of_oracle(task, out["oracle"]) if "oracle" in out else None
    rates: dict[str, float] = {}
    for kind, outs in out.items():
        k, n = sum(bool(o.success) for o in outs), len(outs)
        lo, hi = wilson_interval(k, n)
        rates[kind] = k / n
        mlflow.log_metrics({f"{task}/{split}/{kind}_success_rate": k / n,
                            f"{task}/{split}/{kind}_ci95_low": lo, f"{task}/{split}/{kind}_ci95_high": hi})
        errors = sum(bool(o.error) for o in outs)
        mlflow.log_metric(f"{task}/{split}/{kind}_errors", errors)
        line = f"{task} ({split}) {kind:<11} {format_rate(k, n)}" + (f" ({errors} raised)" if errors else "")
        if families is not None:
            by_family = per_family(outs, families)
            mlflow.log_metrics({f"{task}/{split}/{kind}_family{f}_success_rate": fk / fn
                                for f, (fk, fn) in by_family.items()})
            line += "; " + ", ".join(f"family {f}: {fk}/{fn}" for f, (fk, fn) in by_family.items())
        print(line)
    mlflow.log_dict({kind: [{"seed": o.seed, "plan": list(o.plan), "success": o.success, "measure": o.measure,
                             "fault": o.fault, "error": o.error}
                            | ({} if families is None else {"family": families[i]})
                            for i, o in enumerate(outs)] for kind, outs in out.items()}, f"{task}_{split}_rn_eval.json")
    return rates


def find_pointnet(rn_path: Path, pointnet_path: Path | None) -> Path:
    """``pointnet_path`` if given (checked against the SHA-256 the RN recorded, if any), else the
    ``pointnet-*.pt`` beside ``rn_path`` with that SHA-256; a clear error when the RN records none, no file
    beside it matches, or the given one is another PointNet."""
    from prl.rn_checkpoint import load_rn  # heavy: torch
    from prl.version import file_digest

    model = load_rn(rn_path)
    if pointnet_path is not None:
        check_pointnet(model, Path(pointnet_path))
        return Path(pointnet_path)
    want = model.pointnet_sha256
    if want is None:
        raise ValueError(f"{rn_path} does not record its PointNet; pass --pointnet-path")
    for candidate in sorted(Path(rn_path).parent.glob("pointnet-*.pt")):
        if file_digest(candidate) == want:
            return candidate
    raise FileNotFoundError(f"no pointnet-*.pt beside {rn_path} has the sha256 the RN was trained with "
                            f"({want[:12]}); pass --pointnet-path")


def check_eval_args(task: str, scenes: int, first_seed: int, randomization: float, decodings: Sequence[str]) -> None:
    """ValueError naming an unknown task or decoding, or a bad count, seed or randomisation scale."""
    import envs  # noqa: F401  (registers the hand agent and the tasks)
    from envs.tasks import task_class  # heavy: loads the simulator

    task_class(task)
    for kind in decodings:
        if kind not in DECODINGS:
            hint = f" ({' and '.join(map(repr, BASELINES))} are baselines, always run)" if kind in BASELINES else ""
            raise ValueError(f"unknown RN decoding {kind!r}; known: {', '.join(DECODINGS)}{hint}")
    if scenes < 1:
        raise ValueError(f"scenes must be >= 1, got {scenes}")
    if first_seed < 0:
        raise ValueError(f"first_seed must be >= 0, got {first_seed}")
    if not randomization >= 1.0:
        raise ValueError(f"randomization must be a scale >= 1, got {randomization}")


@flow(name="prl-rn-eval", log_prints=True)
def evaluate_rn(rn_path: str, pointnet_path: str | None = None, task: str = "hammer", first_seed: int = 10_500_000,
                scenes: int = 50, randomization: float = 1.0, decodings: Sequence[str] = DECODINGS,
                frames: int = PipelineConfig.episode_frames, prior_seed: int = PRIOR_SEED_OFFSET) -> dict[str, float]:
    """Run the RN at ``rn_path`` (decoded each way of ``decodings``) and the two baselines on the scenes of
    seeds ``first_seed .. first_seed + scenes - 1`` with ranges scaled by ``randomization``; one MLflow run
    named ``rn-eval``. Returns the success rate per plan kind."""
    from prl.pointnet import load_pointnet  # heavy: trimesh

    check_eval_args(task, scenes, first_seed, randomization, decodings)
    rn, pn = Path(rn_path), find_pointnet(Path(rn_path), None if pointnet_path is None else Path(pointnet_path))
    n_points = load_pointnet(pn).cfg.n_points
    seeds = list(range(first_seed, first_seed + scenes))
    split = "train_ranges" if randomization == 1.0 else f"ranges_x{randomization:g}"
    tracking.configure("prl")
    params = {"rn_path": str(rn), "pointnet_path": str(pn), "task": task, "first_seed": first_seed, "scenes": scenes,
              "randomization": randomization, "decodings": ",".join(decodings), "frames": frames}
    with tracking.parent_run("rn-eval", params=params) as run:
        out = evaluate_in_sim(rn, pn, task, seeds, n_points, frames, randomization, prior_seed, tuple(decodings))
        rates = log_rn_eval(task, split, out)
        print(f"MLflow run {run.info.run_id}")
    return rates


def cli_parser() -> argparse.ArgumentParser:
    """One flag per parameter of the flow ``evaluate_rn``, named like it (``--rn-path`` for ``rn_path``)."""
    parser = argparse.ArgumentParser(prog="python -m flows.evaluate_rn", description=__doc__.split("\n\n")[0])
    parser.add_argument("--rn-path", required=True,
                        help="RN checkpoint (the pipeline's <output-dir>/models/rn-seed<N>.pt)")
    parser.add_argument("--pointnet-path", default=None, help="PointNet checkpoint (default: the one beside the RN)")
    parser.add_argument("--task", default="hammer")
    parser.add_argument("--first-seed", type=int, default=10_500_000,
                        help="first scene seed (the pipeline's own rn-eval uses 10,000,000 + 1,000 x seed)")
    parser.add_argument("--scenes", type=int, default=50)
    parser.add_argument("--randomization", type=float, default=1.0, help="scale of the randomisation ranges")
    parser.add_argument("--decodings", default=",".join(DECODINGS), help="comma-separated RN decodings")
    parser.add_argument("--frames", type=int, default=PipelineConfig.episode_frames,
                        help="physics frames per plan episode")
    parser.add_argument("--prior-seed", type=int, default=PRIOR_SEED_OFFSET,
                        help="seed of the prior-sampled baseline plans")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = cli_parser().parse_args(argv)
    decodings = tuple(d for d in args.decodings.split(",") if d)
    try:
        check_eval_args(args.task, args.scenes, args.first_seed, args.randomization, decodings)
        find_pointnet(Path(args.rn_path), None if args.pointnet_path is None else Path(args.pointnet_path))
    except (ValueError, FileNotFoundError, KeyError) as exc:  # before any flow run or MLflow run starts
        print(f"error: {exc}", file=sys.stderr)
        return 2
    evaluate_rn(args.rn_path, args.pointnet_path, args.task, args.first_seed, args.scenes, args.randomization,
                decodings, args.frames, args.prior_seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
