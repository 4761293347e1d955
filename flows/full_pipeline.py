"""The PRL pipeline as a Prefect flow: ``python -m flows.full_pipeline [--profile paper] [--<field> value] ...``.

The DAG, one module per stage under ``flows/``, each a Prefect task or subflow taking the previous stages'
results and logging its own MLflow child run under the run's parent run::

    assets -> trials-<task> -> synthesis -> labels -> export -> features -> rn-train -> rn-eval -> ln
    assets -> pictures-<task>      assets -> pointnet -> features      synthesis -> export      features -> ln

assets (hand model + PLB) -> plan trials per task (expert, prior-sampled and uniformly random plans
executed on domain-randomised scenes) and stage pictures of the expert plan -> scene synthesis (Dask)
-> label recovery -> LeRobot export -> PointNet and the RN's features -> RN training -> RN evaluation in
simulation -> LN (A2C pre-trained on the demonstrations, one run per task). See the README for how to
look at the runs.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from prefect import flow

from flows.artifacts import markdown_table, publish_summary
from flows.check_assets import assets_stage
from flows.compute_features import features_stage
from flows.evaluate_rn import rn_eval_stage
from flows.export_dataset import export_stage
from flows.plan_trials import run_all_trials, trials_stage
from flows.recover_labels import labels_stage
from flows.stage_pictures import pictures_stage
from flows.synthesize import synthesis_stage
from flows.train_ln import ln_stage
from flows.train_pointnet import pointnet_stage
from flows.train_rn import rn_train_stage
from prl import tracking
from prl.cli import add_config_arguments, config_overrides
from prl.config import PROFILES, ConfigError, PipelineConfig, make_config
from prl.version import code_version, git_commit


@flow(name="prl-full-pipeline", log_prints=True)
def full_pipeline(profile: str = "quick", overrides: dict[str, Any] | None = None) -> dict[str, dict[str, float]]:
    """Run every stage that exists, tracked in MLflow; return success rates per task and plan kind.

    ``overrides`` are ``PipelineConfig`` fields over the profile's, the LN's nested (the command line's flags
    by their field names): e.g. ``{"tasks": ["hammer"], "demos_per_task": 8, "ln": {"timesteps": 64}}``.
    """
    return run_pipeline(make_config(profile, **(overrides or {})))


def run_pipeline(cfg: PipelineConfig) -> dict[str, dict[str, float]]:
    """The flow body (called inside the Prefect flow): the stages in DAG order under one MLflow parent run."""
    if cfg.render or cfg.video:
        from envs.render_probe import require_rendering  # heavy: loads the simulator

        wants = [w for w, on in (("stage pictures (--no-render skips them)", cfg.render),
                                 ("dataset video (--no-video skips it)", cfg.video)) if on]
        require_rendering(" and ".join(wants))
    import envs  # noqa: F401  (registers the hand agent and the tasks)

    uri = tracking.configure("prl")
    version = code_version()
    out_dir = cfg.output_dir / f"run-seed{cfg.seed}"
    out_dir.mkdir(parents=True, exist_ok=True)
    print(f"MLflow store: {uri}; outputs: {out_dir}")
    with tracking.parent_run(f"pipeline-{cfg.profile}", params=cfg,
                             tags={"code_version": version, "git_commit": git_commit()}) as parent:
        assets = assets_stage()
        outcomes = run_all_trials(cfg, version)
        trials = [trials_stage(cfg, assets, name, out_dir, outcomes[name]) for name in cfg.tasks]
        if cfg.render:
            for name in cfg.tasks:
                pictures_stage(assets, name, cfg.seed, out_dir / f"{name}_stages")
        results: dict[str, dict[str, float]] = {t.task: t.rates for t in trials}
        synthesis = synthesis_stage(cfg, trials)
        labels = labels_stage(synthesis, version)
        dataset = export_stage(cfg, synthesis, labels)
        if cfg.train_rn:
            pointnet = pointnet_stage(cfg, assets)
            features = features_stage(cfg, dataset, pointnet)
            rn = rn_train_stage(cfg, features, out_dir)
            rn_eval = rn_eval_stage(cfg, rn, cfg.tasks)
            results.update(rn_eval.rates)
            if cfg.train_ln:
                results.update(ln_stage(cfg, features, rn_eval))
        print(f"MLflow parent run {parent.info.run_id}: mlflow ui --backend-store-uri "
              f"{tracking.resolve_tracking_uri()}, then {tracking.runs_page_url(parent.info.experiment_id)}")
        publish_summary(run_summary(cfg, version, parent.info.run_id, parent.info.experiment_id, dataset, results))
    return results


def run_summary(cfg: PipelineConfig, version: str, run_id: str, experiment_id: str, dataset: Any,
                results: dict[str, dict[str, float]]) -> str:
    """The markdown summary of a run (the ``pipeline-summary`` artifact): settings, where things are, the rates."""
    report = dataset.report
    video = (f"two camera videos {cfg.video_width}x{cfg.video_height}, {cfg.video_fps} pictures/s "
             f"({report.video_codec})" if cfg.video else "no video")
    rows = [{"run": key, "plan": kind, "success rate": round(rate, 3)}
            for key, rates in results.items() for kind, rate in rates.items()]
    models = ("`prl-rn`" + (", `prl-ln`" if cfg.train_ln else "") + " (pt2, no pickle)") if cfg.train_rn else "none"
    return "\n".join([
        f"# prl-full-pipeline: profile {cfg.profile}, seed {cfg.seed}",
        "",
        f"- tasks: {', '.join(cfg.tasks)}; {cfg.demos_per_task} demos per task; code {version} ({git_commit()})",
        (f"- MLflow: parent run `{run_id}` in `{tracking.resolve_tracking_uri()}` (`mlflow ui --backend-store-uri "
         f"{tracking.resolve_tracking_uri()}`, runs at {tracking.runs_page_url(experiment_id)})"),
        (f"- dataset: `{dataset.repo_id}` at `{report.root}`: {report.n_episodes} episodes, {report.n_frames} "
         f"frames at {report.fps} fps, {video}"),
        f"- registered models: {models}",
        "",
        "## Success rates (simulated)",
        "",
        markdown_table(rows),
        "",
        "Tables of this run: " + ", ".join(f"`{k}`" for k in [f"trial-rates-{t}" for t in cfg.tasks]
                                           + ["synthesis-yield", "synthesis-rounds", "label-agreement"]
                                           + (["rn-success"] if cfg.train_rn else [])
                                           + (["ln-success"] if cfg.train_rn and cfg.train_ln else [])),
    ])


CLI_EXCLUDE: tuple[str, ...] = ("profile", *(f"ln.{n}" for n in PipelineConfig.LN_SET_PER_POINT))
"""``PipelineConfig`` fields without a generated flag: the profile (``--profile``, written by hand) and the LN
settings each LN point sets itself."""


def cli_parser() -> argparse.ArgumentParser:
    """The pipeline's command line: ``--profile`` and one flag per ``PipelineConfig`` field (``prl.cli``)."""
    parser = argparse.ArgumentParser(prog="python -m flows.full_pipeline", description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="quick", choices=list(PROFILES),
                        help="named preset (default: quick); the flags below override its settings")
    add_config_arguments(parser, PipelineConfig, exclude=CLI_EXCLUDE)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = cli_parser().parse_args(argv)
    overrides = config_overrides(args, PipelineConfig, exclude=CLI_EXCLUDE)
    try:  # validate before any work starts (and before Prefect spins up)
        make_config(args.profile, **overrides)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    full_pipeline(profile=args.profile, overrides=overrides)
    return 0


if __name__ == "__main__":
    sys.exit(main())
