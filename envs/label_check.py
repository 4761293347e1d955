"""Label agreement per task and dimension on executed plans: ``python -m envs.label_check --scenes 20``.

For each task, the plans of a trial kind (``expert``: the task's own plan; ``prior``: plans sampled from its PLB
prior, as synthesis draws them) are executed on the pipeline's trial scenes; the successful episodes' labels are
recovered from their recordings alone (``prl.label_recovery``) and compared with the commanded plans, per
Representation-Space dimension. Dimensions a task does not act on (``unacted_dims``) are shown but left out of
the acted mean. ``--out`` writes the tables as markdown (``docs/labels.md``).
"""

from __future__ import annotations

import argparse
import datetime
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from envs.execution import ExecutorConfig
from envs.executor import PlanExecutor
from envs.tasks import TASK_ENV_IDS, fast_resets, make_env, task_class
from envs.trials import PLAN_KINDS, kind_seed, plan_set, trial_scene_seeds
from prl.demo import from_episode
from prl.label_recovery import acted_mean, agreement, recover_plan
from prl.plb import load_plb
from prl.version import code_version


def task_agreement(task: str, kind: str, scenes: int, seed: int = 0) -> tuple[np.ndarray, int, int, list[str]]:
    """(per-dimension agreement over the successful episodes, successes, episodes, the misses of each dimension
    as "commanded -> read xN") of ``kind`` plans of ``task`` on its ``scenes`` trial scenes."""
    run_seed = kind_seed(seed, kind)
    plans = plan_set(task, kind, scenes, run_seed)
    env = make_env(task)
    executor = PlanExecutor(env, ExecutorConfig())
    commanded, recovered = [], []
    try:
        with fast_resets():
            for plan, scene in zip(plans, trial_scene_seeds(run_seed, scenes), strict=True):
                result = executor.run(plan, seed=scene)
                if result.success:
                    demo = from_episode(task, scene, "", result, env.unwrapped)
                    commanded.append(list(plan))
                    recovered.append(recover_plan(demo).plan.tolist())
    finally:
        env.close()
    n_ok = len(commanded)
    frac = agreement(np.array(commanded), np.array(recovered)) if n_ok else np.full(6, np.nan)
    return frac, n_ok, scenes, misses(np.array(commanded), np.array(recovered))


def misses(commanded: np.ndarray, recovered: np.ndarray) -> list[str]:
    """Per dimension with a disagreement: ``a<d>: <commanded> -> <read> xN, ...`` in choice names."""
    plb = load_plb()
    out = []
    for d, dim in enumerate(plb.dims):
        pairs = Counter((int(c), int(r)) for c, r in zip(commanded[:, d], recovered[:, d], strict=True) if c != r) \
            if len(commanded) else Counter()
        if pairs:
            names = ["none", *(str(c) for c in dim.choices)]  # index -1 (unread) -> "none"
            out.append(f"a{d}: " + ", ".join(f"{names[c + 1]} -> {names[r + 1]} x{n}" for (c, r), n in pairs.most_common()))
    return out


def markdown(rows: list[tuple[str, str, np.ndarray, int, int, list[str]]], command: str) -> str:
    """The agreement tables as markdown, one row per (task, kind)."""
    plb = load_plb()
    head = "| task | plans | successes used | " + " | ".join(f"a{i} {n}" for i, n in enumerate(plb.dim_names)) \
        + " | acted mean |"
    lines = [
        "# Label agreement per task and dimension",
        "",
        f"*Made by `{command}` on {datetime.date.today().isoformat()}, code {code_version()}.* Each row: the",
        "successful episodes of that plan kind on the task's trial scenes; each cell the share whose label,",
        "recovered from the recording alone, equals the commanded choice. `n/a`: a dimension the task's stages",
        "never act on (its label reads what the scene gives; the expert commands that value).",
        "",
        head,
        "|" + "---|" * (4 + len(plb.dim_names)),
    ]
    for task, kind, frac, n_ok, n, _ in rows:
        unacted = task_class(task).unacted_dims
        cells = ["n/a" if name in unacted else f"{100 * f:.0f}%" for name, f in zip(plb.dim_names, frac, strict=True)]
        mean = acted_mean(frac, plb, unacted) if n_ok else float("nan")
        lines.append(f"| {task} | {kind} | {n_ok}/{n} | " + " | ".join(cells) + f" | {100 * mean:.0f}% |")
    lines += ["", "What the misses read (commanded -> recovered, per dimension):", ""]
    for task, kind, _, _, _, missed in rows:
        lines += [f"- {task} {kind}: " + ("; ".join(missed) if missed else "none")]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default=",".join(TASK_ENV_IDS), help="comma-separated tasks")
    parser.add_argument("--kinds", default="expert", help=f"comma-separated plan kinds of {','.join(PLAN_KINDS)}")
    parser.add_argument("--scenes", type=int, default=20, help="trial scenes per task and kind")
    parser.add_argument("--seed", type=int, default=0, help="the run seed (as the pipeline's --seed)")
    parser.add_argument("--out", default=None, help="write the markdown tables here (e.g. docs/labels.md)")
    args = parser.parse_args(argv)
    tasks = [t.strip() for t in args.tasks.split(",") if t.strip()]
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    bad = [t for t in tasks if t not in TASK_ENV_IDS] + [k for k in kinds if k not in PLAN_KINDS]
    if bad or not tasks or not kinds:
        parser.error(f"unknown task or plan kind {bad or '(none given)'}; tasks: {', '.join(TASK_ENV_IDS)}; "
                     f"kinds: {', '.join(PLAN_KINDS)}")
    if args.scenes < 1:
        parser.error(f"--scenes must be >= 1, got {args.scenes}")
    rows = []
    for task in tasks:
        for kind in kinds:
            frac, n_ok, n, missed = task_agreement(task, kind, args.scenes, args.seed)
            rows.append((task, kind, frac, n_ok, n, missed))
            print(f"{task} {kind}: {n_ok}/{n} successes; agreement " + " ".join(f"{100 * f:.0f}%" for f in frac),
                  flush=True)
    text = markdown(rows, "python -m envs.label_check " + " ".join(argv if argv is not None else sys.argv[1:]))
    if args.out:
        Path(args.out).write_text(text)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
