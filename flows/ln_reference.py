"""The LN results' reference plans (expert, prior-sampled, RN argmax) on the points' scenes, reference-<task>.json.

``python -m flows.ln_reference --tasks hammer,sweep,unscrew,tweeze [--eval-seed 0] [--eval-scenes 50]
[--results-dir docs/results/ln] [--rn-path P] [--extend]``: per task, on the LN points' evaluation scenes
(``envs.trials.eval_scene_seeds(eval_seed, eval_scenes)``, as the sweep's ``--eval-seed`` and ``--eval-scenes``),
the task's expert plan and a plan sampled from its prior per scene (seeded as the RN evaluation's: the eval seed
plus ``flows.evaluate_rn.PRIOR_SEED_OFFSET``), with ``--rn-path`` the RN's argmax plan (``flows.evaluate_rn``: the
PointNet beside the RN with the digest it recorded) and, on a mixed variant, the family oracle, each family's
expert and the best fixed plan the variant's search found (``envs.variant_search.best_fixed_plan``, from the
committed record) are executed, and ``reference-<task>.json`` is written into the results directory
(``prl.ln_reference``); ``python -m flows.report`` shows them next to the points. A reference whose task, settings
and code version equal today's is kept (printed); else it is computed again and replaced, saying why. Run it with
the same ``--rn-path`` to keep an RN's rows: without one, the settings differ and the reference is replaced by one
without the RN. ``--extend`` keeps a committed reference that is current but for its best fixed plan (none yet, or
the search's record now names another) and runs only that plan, so its RN rows stay without the RN at hand. An
unknown task or a missing RN file is an error before anything runs (exit status 2). No MLflow run: the files are
the record.
"""

from __future__ import annotations

import argparse
import datetime
import sys
from pathlib import Path
from typing import Any

from envs.variant_search import best_fixed_plan
from flows.evaluate_rn import PRIOR_SEED_OFFSET, baseline_outcomes, find_pointnet, rn_outcomes
from prl.config import check_task_names
from prl.constants import EPISODE_FRAMES, REPO_ROOT
from prl.ln_reference import (
    plan_result,
    read_reference,
    reference_file_name,
    reference_kinds,
    reference_reuse,
    write_reference,
)
from prl.task_registry import known_tasks
from prl.version import file_digest, outcome_file_digests, version_of

RN_SETTINGS: tuple[str, ...] = ("rn", "rn_sha256", "pointnet", "n_points")
"""The settings that name a reference's RN (``reference_settings``)."""

REFERENCE_PROCEDURE = 1
"""Version of what this command computes for a reference (the plans, their seeds, the RN's decoding), a setting of
every reference: bump it when a change here or in ``flows.evaluate_rn`` changes a reference's outcome."""
RESULTS_DIR = REPO_ROOT / "docs" / "results" / "ln"
"""The committed results (the point summaries and the references)."""


def reference_settings(eval_seed: int, eval_scenes: int, n_frames: int = EPISODE_FRAMES, rn_path: Path | None = None,
                       pointnet_path: Path | None = None, n_points: int | None = None) -> dict[str, Any]:
    """What decides a reference's outcome beside its code version (``prl.ln_reference``): the evaluation's scene
    seed and count, the frames, the prior plans' seed, the procedure and, with an RN, its file name and digest, its
    PointNet's file name and the surface points. File names only: no local path."""
    settings: dict[str, Any] = {"eval_seed": int(eval_seed), "eval_scenes": int(eval_scenes),
                                "n_frames": int(n_frames), "prior_seed": int(eval_seed) + PRIOR_SEED_OFFSET,
                                "procedure": REFERENCE_PROCEDURE}
    if rn_path is not None:
        settings.update(rn=Path(rn_path).name, rn_sha256=file_digest(rn_path), pointnet=Path(pointnet_path).name,
                        n_points=int(n_points))
    return settings


def reference_decision(results_dir: Path, record: dict[str, Any]) -> tuple[dict[str, Any] | None, str]:
    """The committed reference of ``record``'s task to keep (None: compute it) and a line saying why.
    ``prl.ln_summary.SummaryError`` naming a malformed file."""
    path = Path(results_dir) / reference_file_name(record["task"])
    existing = read_reference(path) if path.is_file() else None
    keep, why = reference_reuse(existing, record)
    if keep:
        return existing, f"{path.name}: kept ({why})"
    return None, f"{path.name}: computing ({why})"


def evaluation_seeds(eval_seed: int, eval_scenes: int) -> list[int]:
    """The points' evaluation scenes: ``envs.trials.eval_scene_seeds``, as the sweep derives them."""
    from envs.trials import eval_scene_seeds  # heavy: loads the simulator

    return eval_scene_seeds(eval_seed, eval_scenes)


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def extendable(existing: dict[str, Any] | None, record: dict[str, Any]) -> str | None:
    """Why ``--extend`` cannot keep ``existing`` for ``record`` (None: it can): there must be one, of the same code
    version and the same settings but for the RN's (kept) and the best fixed plan (run again)."""
    if existing is None:
        return "there is no committed reference to extend"
    if existing["code_version"] != record["code_version"]:
        return f"its code version {existing['code_version']} is not today's {record['code_version']}"
    own = ("best_fixed", *RN_SETTINGS)
    mine = {k: v for k, v in existing["settings"].items() if k not in own}
    theirs = {k: v for k, v in record["settings"].items() if k not in own}
    return None if mine == theirs else f"its settings {mine} are not the command's {theirs}"


def extend_reference(existing: dict[str, Any], record: dict[str, Any], seeds: list[int]) -> dict[str, Any]:
    """``existing`` with its best fixed plan set to ``record``'s and run again on ``seeds`` (removed where
    ``record`` has none); every other row kept."""
    settings = {k: v for k, v in existing["settings"].items() if k != "best_fixed"}
    plans = {k: v for k, v in existing["plans"].items() if k != "best_fixed"}
    if "best_fixed" in record["settings"]:
        settings["best_fixed"] = record["settings"]["best_fixed"]
        plans["best_fixed"] = plan_result(best_fixed_outcomes(record["task"], settings, seeds))
    return {**existing, "settings": settings, "plans": plans, "finished": _now()}


def best_fixed_outcomes(task_name: str, settings: dict[str, Any], seeds: list[int]) -> list:
    """``settings['best_fixed']`` executed on every one of ``seeds``' scenes."""
    from envs.trials import run_trials  # heavy: loads the simulator

    return run_trials(task_name, [list(settings["best_fixed"])] * len(seeds), seeds, n_frames=settings["n_frames"],
                      randomization=1.0)


def run_reference(record: dict[str, Any], seeds: list[int], rn_path: Path | None = None,
                  pointnet_path: Path | None = None) -> dict[str, Any]:
    """Execute ``record``'s plan kinds on ``seeds``' scenes (``flows.evaluate_rn.baseline_outcomes`` and, with an
    RN, ``rn_outcomes`` decoded 'rn', the argmax); returns the reference summary (``prl.ln_reference``)."""
    task_name, settings = record["task"], record["settings"]
    started = _now()
    out = baseline_outcomes(task_name, seeds, settings["n_frames"], 1.0, settings["prior_seed"])
    if rn_path is not None:
        out.update(rn_outcomes(rn_path, pointnet_path, task_name, seeds, settings["n_points"], settings["n_frames"],
                               1.0, ("rn",)))
    if "best_fixed" in settings:
        out["best_fixed"] = best_fixed_outcomes(task_name, settings, seeds)
    plans = {kind: plan_result(out[kind]) for kind in reference_kinds(out)}
    return {**record, "plans": plans, "started": started, "finished": _now()}


def check_arguments(tasks: list[str], eval_seed: int, eval_scenes: int, rn_path: Path | None) -> None:
    """ValueError naming an unknown task or a bad seed or count; FileNotFoundError naming a missing RN file."""
    check_task_names(tasks)
    if eval_seed < 0:
        raise ValueError(f"--eval-seed must be >= 0, got {eval_seed}")
    if eval_scenes < 1:
        raise ValueError(f"--eval-scenes must be >= 1, got {eval_scenes}")
    if rn_path is not None and not Path(rn_path).is_file():
        raise FileNotFoundError(f"--rn-path {str(rn_path)!r}: no such RN checkpoint")


def cli_parser() -> argparse.ArgumentParser:
    """The command line (defaults: the sweep's evaluation scenes, the committed results directory)."""
    parser = argparse.ArgumentParser(prog="python -m flows.ln_reference", description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", required=True, help=f"comma-separated tasks, of {','.join(known_tasks())}")
    parser.add_argument("--eval-seed", type=int, default=0, help="the sweep's --eval-seed (the scenes' run seed)")
    parser.add_argument("--eval-scenes", type=int, default=50, help="the sweep's --eval-scenes")
    parser.add_argument("--results-dir", type=Path, default=RESULTS_DIR, help="where reference-<task>.json go")
    parser.add_argument("--rn-path", type=Path, default=None,
                        help="an RN checkpoint (its PointNet beside it) whose argmax plan joins the references")
    parser.add_argument("--extend", action="store_true",
                        help="keep a current reference's rows (its RN's too) and run only its best fixed plan")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = cli_parser().parse_args(argv)
    tasks = [t.strip() for t in args.tasks.split(",") if t.strip()]
    try:  # before anything runs
        check_arguments(tasks, args.eval_seed, args.eval_scenes, args.rn_path)
        pointnet = n_points = None
        if args.rn_path is not None:
            from prl.pointnet import load_pointnet  # heavy: torch, trimesh

            pointnet = find_pointnet(args.rn_path, None)
            n_points = load_pointnet(pointnet).cfg.n_points
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    seeds = evaluation_seeds(args.eval_seed, args.eval_scenes)
    settings = reference_settings(args.eval_seed, args.eval_scenes, EPISODE_FRAMES, args.rn_path, pointnet, n_points)
    for task_name in tasks:
        files = outcome_file_digests(task_name, "reference")
        best = best_fixed_plan(task_name)
        record = {"task": task_name, "settings": {**settings, **({"best_fixed": best} if best else {})},
                  "code_version": version_of(files), "code_files": files}
        existing, note = reference_decision(args.results_dir, record)
        if args.extend and existing is None:
            path = Path(args.results_dir) / reference_file_name(task_name)
            committed = read_reference(path) if path.is_file() else None
            why = extendable(committed, record)
            if why:
                print(f"error: --extend {task_name}: {why}", file=sys.stderr)
                return 2
            existing, note = extend_reference(committed, record, seeds), f"{path.name}: extending its best fixed plan"
            write_reference(args.results_dir, existing)
        print(note, flush=True)
        ref = existing or run_reference(record, seeds, args.rn_path, pointnet)
        if existing is None:
            print(f"{task_name}: written to {write_reference(args.results_dir, ref)}")
        print(f"{task_name} on {len(seeds)} scenes: " + ", ".join(
            f"{kind} {r['successes']}/{r['n']}" for kind, r in ref["plans"].items()), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
