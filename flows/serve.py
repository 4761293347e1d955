"""Serve the pipeline's deployments to a Prefect server: ``python -m flows.serve``.

With a server running (``prefect server start``) and ``PREFECT_API_URL`` pointing at it, this
process registers the deployments and executes their runs; trigger one with e.g.

    prefect deployment run 'prl-full-pipeline/quick'
    prefect deployment run 'prl-full-pipeline/quick' \
        --param overrides='{"demos_per_task": 8, "ln": {"timesteps": 128}}'
    prefect deployment run 'prl-full-pipeline/paper'
    prefect deployment run 'prl-rn-eval/default' --param rn_path=/tmp/rnrun/models/rn-seed0.pt
    prefect deployment run 'prl-ln-ablation/default' --param dataset_root=outputs/datasets/hammer-seed0 \
        --param pointnet_path=outputs/models/pointnet-<key>.pt --param overrides='{"seeds": [0, 1, 2]}'
    prefect deployment run 'prl-imitation/default' --param dataset_root=outputs/datasets/hammer-seed0 \
        --param overrides='{"steps": 2000}'

``overrides`` are the fields of ``prl.config.PipelineConfig`` / ``AblationConfig`` (the LN's nested under
``ln``), named like the command line's flags (``--demos-per-task`` is ``demos_per_task``, ``--ln-timesteps``
is ``{"ln": {"timesteps": ...}}``).

Runs execute in this process, with the repo as working directory, so they use the same
MLflow store (``<repo>/mlflow.db``) as ``python -m flows.full_pipeline``.
"""

from __future__ import annotations

from prefect import serve

from flows.ablation import ablation
from flows.evaluate_rn import evaluate_rn
from flows.full_pipeline import full_pipeline
from flows.imitation import imitation


def main() -> None:
    serve(
        full_pipeline.to_deployment(name="quick", parameters={"profile": "quick"},
                                    description='Quick profile: minutes on a laptop. overrides: PipelineConfig '
                                    'fields, e.g. {"demos_per_task": 8, "ln": {"timesteps": 128}}.'),
        full_pipeline.to_deployment(name="paper", parameters={"profile": "paper"},
                                    description="The paper's scale (2,000 demos per task). overrides: "
                                    "PipelineConfig fields."),
        evaluate_rn.to_deployment(name="default", description="A trained RN checkpoint in simulation on unseen "
                                  "scenes (rn_path required; pointnet_path, task, first_seed, scenes, "
                                  "randomization, decodings, frames, prior_seed)."),
        ablation.to_deployment(name="default", description="The LN ablation sweep (Fig 8): dataset_root and "
                               "pointnet_path required; overrides: AblationConfig fields (tasks, methods, "
                               "demo_steps, seeds, eval_scenes, workers, ..., ln: {timesteps, ...})."),
        imitation.to_deployment(name="default", description="A LeRobot policy (ACT) trained on a dataset's demos "
                                "of one task and rolled out in the joint-control environment: dataset_root "
                                "required; task_name, demos, eval_seed, eval_scenes, output_dir; overrides: "
                                "ImitationConfig fields (steps, batch_size, chunk_size, ...)."),
    )


if __name__ == "__main__":
    main()
