"""The LN ablation sweep (paper Fig 8) as a Prefect flow: ``python -m flows.ablation --dataset-root D --pointnet-path P``
(neither for a sweep of ``--methods joint`` alone).

Points = tasks x methods x demonstration steps x seeds (``flows.train_ln.LNPoint``: physics-guided A2C for each
K, BC, joint_bc and imitation for each K > 0, joint control once), fanned out over the same Dask task runner as synthesis, each
point one MLflow child run under one sweep parent run. The sweep is resumable and can grow: the parent
run is found again by a key over the sweep's settings (not its list of points), and points that already
have a finished child run and a summary are not re-run, so adding seeds or methods runs only the new ones.
``--reevaluate`` executes the finished points' saved final policies again on the evaluation scenes (after a
task's success criterion changed) and replaces their ``eval`` without retraining. At the end Fig 8 is drawn
from the points' runs: success rate against timesteps and against physics frames, mean over seeds with a
min-max band (top: physics-guided vs joint control; bottom: demonstration steps); ``--draw-from`` redraws it
from the summaries of one or more sweeps' output directories.

With ``--results-dir`` (the experiment: ``docs/results/ln``) each finished point also writes its committed summary
there, and the points whose committed summary holds today's settings (the dataset's recipe among them) and code
version count as done whatever the MLflow store holds (``flows.ln_results``: what invalidates one);
``python -m flows.report`` makes ``docs/results.md`` from them.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
import time
from pathlib import Path
from typing import Any

from prefect import flow

from flows.ln_results import committed_summaries, ln_committed_point, point_records
from flows.train_ln import LNPoint, LNSetup, ln_point, ln_reevaluate, write_demonstrations
from prl import tracking
from prl.cli import add_config_arguments, config_overrides
from prl.config import AblationConfig, LNConfig, make_ablation_config
from prl.plots import plot_learning_curves

PAPER_DEMO_STEPS: tuple[int, ...] = (0, 320, 640, 1280, 2560)
"""The paper's demonstration-step ablation."""


def sweep_points(tasks: list[str], methods: list[str], demo_steps: list[int], seeds: list[int]) -> list[LNPoint]:
    """Every point of a sweep, in a fixed order (``LNPoint`` checks each: an unknown method, a negative K)."""
    points = []
    for task_name in tasks:
        for method in methods:
            steps = [0] if method == "joint" else [k for k in demo_steps if method in ("physics", "physics_gated") or k > 0]
            for k in steps:
                points.extend(LNPoint(task_name, method, int(k), int(s)) for s in seeds)
    if not points:
        raise ValueError(f"the sweep has no point (methods {methods}, demo steps {demo_steps}, seeds {seeds})")
    return points


def finished_points(parent_run_id: str) -> set[str]:
    """Names of the points that have a FINISHED child run under ``parent_run_id``."""
    import mlflow  # heavy: mlflow

    runs = mlflow.search_runs(filter_string=f"tags.mlflow.parentRunId = '{parent_run_id}' and "
                                            f"attributes.status = 'FINISHED'", output_format="list")
    return {r.data.tags.get("ln_point", "") for r in runs} - {""}


def sweep_settings(cfg: AblationConfig) -> dict[str, Any]:
    """What makes two sweeps the same (their points aside): the parent run's params, hashed into its key. The LN
    settings beyond the first keys, and the imitation's, enter only where they differ from the defaults, so that
    earlier sweeps keep their key."""
    first = ("timesteps", "pretrain_epochs", "steps_per_update")
    paper = LNConfig()
    changed = {f"ln.{f.name}": getattr(cfg.ln, f.name) for f in dataclasses.fields(LNConfig)
               if f.name not in first and f.name not in cfg.LN_SET_PER_POINT
               and getattr(cfg.ln, f.name) != getattr(paper, f.name)}
    imitation = type(cfg.imitation)()
    changed |= {f"imitation.{f.name}": getattr(cfg.imitation, f.name) for f in dataclasses.fields(imitation)
                if f.name != "seed" and getattr(cfg.imitation, f.name) != getattr(imitation, f.name)}
    paths = {name: None if getattr(cfg, name) is None else str(getattr(cfg, name).resolve())
             for name in ("dataset_root", "pointnet_path")}
    return {"dataset_root": paths["dataset_root"], "pointnet": paths["pointnet_path"],
            "timesteps": cfg.ln.timesteps, "eval_scenes": cfg.eval_scenes, "eval_seed": cfg.eval_seed,
            "pretrain_epochs": cfg.ln.pretrain_epochs, "n_points": cfg.n_points,
            "steps_per_update": cfg.ln.steps_per_update, **changed}


def _sweep_key(settings: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(settings, sort_keys=True, default=str).encode()).hexdigest()[:12]


def _parent(key: str, name: str, settings: dict[str, Any]) -> Any:
    """The sweep's parent run: the one tagged with ``key`` if it exists (resume), else a new one."""
    import mlflow  # heavy: mlflow

    found = mlflow.search_runs(filter_string=f"tags.sweep_key = '{key}'", output_format="list",
                               order_by=["attributes.start_time DESC"], max_results=1)
    while mlflow.active_run() is not None:
        mlflow.end_run()
    if found:
        return mlflow.start_run(run_id=found[0].info.run_id)
    run = mlflow.start_run(run_name=name, tags={"sweep_key": key})
    mlflow.log_params(tracking.flatten_params(settings))
    return run


@flow(name="prl-ln-ablation", log_prints=True)
def ablation(dataset_root: str | None, pointnet_path: str | None,
             overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Run (or resume) the sweep; return ``{point name: summary}`` and draw Fig 8 into its ``output_dir``. A sweep
    of joint control alone needs no dataset and no PointNet (None).

    ``overrides`` are ``prl.config.AblationConfig`` fields, the LN's nested (the command line's flags by their
    field names): e.g. ``{"seeds": [0, 1, 2], "demo_steps": [0, 1280], "ln": {"timesteps": 3200}}``.
    """
    import mlflow  # heavy: mlflow

    from envs.trials import eval_scene_seeds
    from flows.compute_features import rn_features
    from flows.synthesize import make_task_runner
    from prl.export_schema import read_scenes, require_feature
    from prl.imitation import IMITATION_INPUTS

    cfg = make_ablation_config(dataset_root, pointnet_path, **(overrides or {}))
    tasks = list(cfg.tasks)
    points = sweep_points(tasks, list(cfg.methods), list(cfg.demo_steps), list(cfg.seeds))
    root = cfg.dataset_root
    plan_tasks = list(dict.fromkeys(p.task for p in points if p.method != "joint"))
    scenes = read_scenes(root) if plan_tasks else []  # FileNotFoundError naming a missing dataset, before any work
    for p in points:  # K beyond the demonstrations available (one per episode): an error before any work
        available = sum(s["task"] == p.task for s in scenes)
        if p.method != "joint" and not available:  # the plan env's x is standardised with the demos' statistics
            raise ValueError(f"the dataset {str(root)!r} has no {p.task} demonstration; point {p.name} needs some")
        if p.demo_steps > available:
            raise ValueError(f"demo_steps={p.demo_steps} exceeds the {available} {p.task} demonstrations in "
                             f"{str(root)!r}; synthesise more or sweep fewer steps")
    if any(p.method == "imitation" for p in points):  # the policy reads what the joint-control env observes
        features = json.loads((root / "meta" / "info.json").read_text())["features"]
        for name in IMITATION_INPUTS:
            require_feature(features, name, root)
    out = cfg.output_dir
    results_dir = cfg.results_dir.resolve() if cfg.results_dir is not None else None
    settings = sweep_settings(cfg)
    key = _sweep_key(settings)  # the points are left out: a sweep given more seeds or methods resumes
    setup = LNSetup(demo_dir=out / "demos", pointnet_path=cfg.pointnet_path, out_dir=out / "points",
                    eval_seeds=tuple(eval_scene_seeds(cfg.eval_seed, cfg.eval_scenes)), ln=cfg.ln,
                    n_points=cfg.n_points, progress=False, dataset_root=root, imitation=cfg.imitation)
    workers, dask_address = cfg.workers, cfg.dask_address
    tracking.configure("prl")
    with _parent(key, f"ln-ablation-{key}", settings) as parent:
        if not all((setup.demo_dir / f"demos-{t}.npz").is_file() for t in plan_tasks):
            repo_id = cfg.repo_id or _repo_id_of(root)
            counts = write_demonstrations(setup.demo_dir, plan_tasks, rn_features(root, repo_id, cfg.pointnet_path,
                                                                                  cfg.n_points))
            print("demonstrations per task: " + ", ".join(f"{t} {n}" for t, n in counts.items()))
        done = finished_points(parent.info.run_id)
        summaries = {p.name: json.loads((setup.out_dir / f"{p.name}.json").read_text()) for p in points
                     if p.name in done and (setup.out_dir / f"{p.name}.json").is_file()}
        records: dict[str, Any] = {}
        if results_dir is not None:  # the committed summaries decide what is done, not this store
            records = point_records(points, setup, root, cfg.eval_seed)
            summaries, notes = committed_summaries(points, results_dir, records)
            notes += [f"{name}: finished in this MLflow sweep, but without a valid summary in {str(results_dir)!r}: "
                      f"re-run" for name in sorted((done & set(records)) - set(summaries))]
            print("\n".join([f"{len(summaries)} points done in {str(results_dir)!r}", *notes]))
        todo = [p for p in points if p.name not in summaries]
        print(f"sweep {key}: {len(points)} points, {len(summaries)} already finished, {len(todo)} to run "
              f"(MLflow parent {parent.info.run_id})")
        if cfg.reevaluate and summaries:
            print(f"re-evaluating {len(summaries)} finished points' final policies on {cfg.eval_scenes} scenes")
            summaries.update(_reevaluate(list(summaries.values()), setup, workers, dask_address, make_task_runner))
        if todo:
            summaries.update(_fan_out(todo, setup, parent.info.run_id, workers, dask_address, make_task_runner,
                                      records, results_dir))
        for name, fig in draw_fig8(summaries, out).items():
            mlflow.log_figure(fig, name)
        table = {name: s["eval"] | {"train_seconds": s["train_seconds"]} for name, s in summaries.items()}
        for name, s in sorted(table.items()):
            print(f"{name}: {s['successes']}/{s['n']} on unseen scenes (95% CI {s['ci95'][0]:.2f}-{s['ci95'][1]:.2f})")
    return summaries


def _fan_out(todo: list[LNPoint], setup: LNSetup, parent_id: str, workers: int, dask_address: str | None,
             make_task_runner: Any, records: dict[str, Any], results_dir: Path | None) -> dict[str, Any]:
    @flow(name="prl-ln-points", task_runner=make_task_runner(workers, dask_address))
    def _points(todo: list[LNPoint]) -> list[dict[str, Any]]:
        if results_dir is None:
            futures = [ln_point.submit(p, setup, parent_id) for p in todo]
        else:
            futures = [ln_committed_point.submit(p, setup, parent_id, records[p.name], results_dir) for p in todo]
        _watch(parent_id, {p.name for p in todo}, sum(setup.imitation.steps if p.method == "imitation"
                                                      else setup.ln.timesteps for p in todo), futures)
        return [f.result() for f in futures]

    return {s["name"]: s for s in _points(todo)}


def _reevaluate(finished: list[dict[str, Any]], setup: LNSetup, workers: int, dask_address: str | None,
                make_task_runner: Any) -> dict[str, Any]:
    @flow(name="prl-ln-reevaluate", task_runner=make_task_runner(workers, dask_address))
    def _points(finished: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return [f.result() for f in [ln_reevaluate.submit(s, setup) for s in finished]]

    return {s["name"]: s for s in _points(finished)}


def _watch(parent_id: str, names: set[str], total: int, futures: list, period_s: float = 10.0) -> None:
    """A progress bar over the sweep's steps, read from the points' metrics in MLflow: RL timesteps
    (``ln/timesteps``) and imitation gradient steps (``imitation/steps``)."""
    import mlflow  # heavy: mlflow
    from tqdm.auto import tqdm

    with tqdm(total=total, desc="LN sweep", unit="step") as bar:
        while not all(f.wrapped_future.done() for f in futures):
            runs = mlflow.search_runs(filter_string=f"tags.mlflow.parentRunId = '{parent_id}'", output_format="list")
            done = latest_point_runs(runs, names)
            bar.n = int(sum(r.data.metrics.get("ln/timesteps", 0.0) + r.data.metrics.get("imitation/steps", 0.0)
                            for r in done))
            bar.set_postfix(points_finished=sum(r.info.status == "FINISHED" for r in done))
            bar.refresh()
            time.sleep(period_s)


def latest_point_runs(runs: list[Any], names: set[str]) -> list[Any]:
    """Of MLflow runs tagged ``ln_point``, the latest started per point in ``names``: a point killed and run again
    under the same sweep parent has two child runs, and only the one running now counts its timesteps."""
    latest: dict[str, Any] = {}
    for r in runs:
        name = r.data.tags.get("ln_point")
        if name in names and (name not in latest or r.info.start_time > latest[name].info.start_time):
            latest[name] = r
    return list(latest.values())


def _repo_id_of(root: Path) -> str:
    info = json.loads((root / "meta" / "info.json").read_text()) if (root / "meta" / "info.json").is_file() else {}
    return str(info.get("repo_id") or f"prl/{root.name}")


def draw_fig8(summaries: dict[str, Any], out: Path) -> dict[str, Any]:
    """Fig 8 from the points' curves: per task, physics-guided (largest K, and K = 0) vs BC vs joint control,
    and the demonstration-step curves; each against timesteps and against physics frames. Saved in ``out``;
    returns {file name: figure}."""
    figs = {}
    by_task: dict[str, dict[str, list]] = {}
    for s in summaries.values():
        p = s["point"]
        if not s["rows"]:  # imitation: no RL update, its curve is a loss
            continue
        label = f"{p['method']} K={p['demo_steps']}"
        if p["method"] == "joint":  # named by its budget: an equal-frames run is 15x to 75x longer
            label = f"joint control, {int(s['rows'][-1]['timesteps']) if s['rows'] else 0:,} steps"
        by_task.setdefault(p["task"], {}).setdefault(label, []).append(s["rows"])
    for task_name, curves in sorted(by_task.items()):
        for x_key, x_label in (("timesteps", "timesteps (RL steps)"), ("frames", "simulated physics frames")):
            name = f"fig8_{task_name}_{x_key}.png"
            figs[name] = plot_learning_curves(dict(sorted(curves.items())), x_key, "window_success_rate", out / name,
                                              title=f"{task_name}: LN methods", x_label=x_label, log_x=True)
    return figs


def read_summaries(sweep_dirs: list[str]) -> dict[str, Any]:
    """The point summaries (``points/*.json``) of one or more sweep output directories, told apart by name and
    timesteps (a later directory's identical point wins). ``FileNotFoundError`` naming a directory without any."""
    summaries: dict[str, Any] = {}
    for d in sweep_dirs:
        found = sorted((Path(d) / "points").glob("ln-*.json"))
        if not found:
            raise FileNotFoundError(f"no LN point summaries under {str(Path(d) / 'points')!r}")
        for path in found:
            s = json.loads(path.read_text())
            summaries[f"{s['name']}@{int(s['rows'][-1]['timesteps']) if s['rows'] else 0}"] = s
    return summaries


CLI_EXCLUDE: tuple[str, ...] = (*(f"ln.{n}" for n in AblationConfig.LN_SET_PER_POINT),
                                 *(f"imitation.{n}" for n in AblationConfig.IMITATION_SET_PER_POINT))
"""``AblationConfig`` fields without a generated flag: the LN and imitation settings each sweep point sets itself."""


def cli_parser() -> argparse.ArgumentParser:
    """The sweep's command line: one flag per ``AblationConfig`` field (``prl.cli``), and ``--draw-from``."""
    parser = argparse.ArgumentParser(prog="python -m flows.ablation", description=__doc__.splitlines()[0],
                                     epilog=f"The paper's demonstration-step ablation: --demo-steps "
                                            f"{','.join(map(str, PAPER_DEMO_STEPS))}.")
    add_config_arguments(parser, AblationConfig, exclude=CLI_EXCLUDE)
    parser.add_argument("--draw-from", default=None, metavar="DIR,DIR",
                        help="only redraw Fig 8 into --output-dir from these sweeps' output directories (no run)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = cli_parser()
    args = parser.parse_args(argv)
    overrides = config_overrides(args, AblationConfig, exclude=CLI_EXCLUDE)
    if args.draw_from:
        try:
            figs = draw_fig8(read_summaries(args.draw_from.split(",")),
                             Path(overrides.get("output_dir", AblationConfig.output_dir)))
        except FileNotFoundError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        out = Path(overrides.get("output_dir", AblationConfig.output_dir))
        print("\n".join(str(out / name) for name in figs))
        return 0
    dataset_root, pointnet_path = overrides.pop("dataset_root", None), overrides.pop("pointnet_path", None)
    try:  # before any flow run or MLflow run starts
        cfg = make_ablation_config(dataset_root, pointnet_path, **overrides)
        sweep_points(list(cfg.tasks), list(cfg.methods), list(cfg.demo_steps), list(cfg.seeds))
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    ablation(dataset_root, pointnet_path, overrides)
    return 0


if __name__ == "__main__":
    sys.exit(main())
