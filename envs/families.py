"""The scene families of the mixed task variants (issue #26): the family oracle, outcomes per family, and whether one
fixed plan could do what the RN and the LN do.

A mixed variant (``envs/tasks/<task>_mixed.py``, ``envs.tasks.mixed.MixedFamilies``) draws each scene from one of
several families that need different plans; ``scene_params["family"]`` says which, and ``family_expert_plans`` holds
each family's hand-written plan. Here, as references (never as a policy's input):

- ``oracle``: on each scene its own family's expert plan (read from the scene after reset, as a reference may);
- ``family <k> expert``: family k's plan on every scene;
- the best single fixed plan: the best of the families' experts and of the most frequent successful plans in the
  variant's demos (the target of #26: <= 60%, so that a network must read x to do better).

``python -m envs.families --task unscrew_mixed --scenes 50 [--dataset-root D --repo-id R] [--top 20]`` prints them
on the pipeline's trial scenes with 95% Wilson intervals, per family; with ``--uniform`` it prints instead the
uniformly random plans of ``python -m envs.trials --kinds uniform`` (the same plans on the same scenes) per family.
With ``--decodings`` (and ``--dataset-root``) it adds what each RN decoding would execute if the RN read each scene's
family perfectly and returned that family's demo marginals (``family_decodings``): whether reading the family alone
is enough for each decoding on these demos.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from prl.constants import EPISODE_FRAMES
from prl.plb import load_plb
from prl.proposal import weighted_choice_freqs
from prl.rn_policy import DECODINGS
from prl.stats import format_rate


def family_plans(task: str) -> dict[int, tuple[int, ...]] | None:
    """``task``'s family -> expert plan table, or None for a task without families; ``ValueError`` naming an
    unknown task."""
    from envs.tasks import task_class  # heavy: loads the simulator

    cls = task_class(task)
    plans = getattr(cls, "family_expert_plans", None)
    return None if not plans else {int(k): tuple(int(v) for v in p) for k, p in plans.items()}


def oracle_outcomes(task: str, seeds: Sequence[int], n_frames: int = EPISODE_FRAMES,
                    randomization: float = 1.0) -> list[Any]:
    """The family oracle on ``seeds``' scenes: each scene's own family's expert plan (``envs.trials.TrialOutcome``
    each; ``families_of_oracle`` reads the families back). ``ValueError`` for a task without families."""
    from envs.trials import run_policy  # heavy: loads the simulator

    plans = family_plans(task)
    if plans is None:
        raise ValueError(f"task {task!r} has no scene families (no family_expert_plans): no oracle")
    return run_policy(task, lambda i, env, x_manip: plans[int(env.scene_params["family"])], seeds,
                      n_frames=n_frames, randomization=randomization, desc=f"{task} family oracle")


def family_outcomes(task: str, seeds: Sequence[int], n_frames: int = EPISODE_FRAMES, randomization: float = 1.0,
                    ran: Mapping[tuple[int, ...], list[Any]] | None = None) -> dict[str, list[Any]]:
    """The oracle and every family's expert (``family <k> expert``) on ``seeds``' scenes; ``{}`` for a task without
    families. ``ran``: outcomes of plans already executed on these scenes with these settings, by plan (the task's
    expert is family 0's plan), reused instead of run again."""
    from envs.trials import run_trials  # heavy: loads the simulator

    plans = family_plans(task)
    if plans is None:
        return {}
    ran = ran or {}
    out = {"oracle": oracle_outcomes(task, seeds, n_frames, randomization)}
    for k, plan in plans.items():
        out[f"family {k} expert"] = ran.get(plan) or run_trials(task, [plan] * len(seeds), list(seeds),
                                                                n_frames=n_frames, randomization=randomization)
    return out


def uniform_outcomes(task: str, n: int, run_seed: int = 0, randomization: float = 1.0) -> tuple[list[Any], list[int]]:
    """The uniformly random plans of ``python -m envs.trials --task <task> --scenes <n> --kinds uniform`` on its
    scenes (the same plans and scene seeds, so the same outcomes), and each scene's family, read from the scene
    after its reset as a reference may (-1 where the reset raised): the issue's "uniform plans <= 10%", per family."""
    from envs.trials import kind_seed, plan_set, run_policy, trial_scene_seeds  # heavy: loads the simulator

    seed = kind_seed(run_seed, "uniform")
    plans = plan_set(task, "uniform", n, seed)
    family: dict[int, int] = {}

    def policy(i: int, env: Any, x_manip: Any) -> tuple[int, ...]:
        family[i] = int(env.scene_params["family"])
        return plans[i]

    outcomes = run_policy(task, policy, trial_scene_seeds(seed, n), randomization=randomization,
                          desc=f"{task} uniform plans")
    return outcomes, [family.get(i, -1) for i in range(n)]


def families_of_oracle(task: str, oracle: Sequence[Any]) -> list[int]:
    """Each scene's family, read back from the plan the oracle ran on it (the families' plans differ:
    ``MixedFamilies.check_families``); -1 for a scene that raised before the oracle chose (no plan)."""
    plans = family_plans(task)
    if plans is None:
        raise ValueError(f"task {task!r} has no scene families (no family_expert_plans)")
    family_of = {plan: family for family, plan in plans.items()}
    return [family_of.get(tuple(int(v) for v in o.plan), -1) for o in oracle]


def per_family(outcomes: Sequence[Any], families: Sequence[int]) -> dict[int, tuple[int, int]]:
    """``{family: (successes, scenes)}`` of ``outcomes`` (one per scene, in the order of ``families``)."""
    if len(outcomes) != len(families):
        raise ValueError(f"{len(outcomes)} outcomes but {len(families)} families")
    table: dict[int, list[int]] = {}
    for outcome, family in zip(outcomes, families, strict=True):
        row = table.setdefault(int(family), [0, 0])
        row[0] += bool(outcome.success)
        row[1] += 1
    return {f: (k, n) for f, (k, n) in sorted(table.items())}


def frequent_plans(plans: Sequence[Sequence[int]], top: int) -> list[tuple[tuple[int, ...], int]]:
    """The ``top`` most frequent plans of ``plans`` with their counts, most frequent first (ties: the plan that
    appears first)."""
    if top < 1:
        raise ValueError(f"top must be >= 1, got {top}")
    return Counter(tuple(int(v) for v in p) for p in plans).most_common(top)


def family_line(name: str, outcomes: Sequence[Any], families: Sequence[int]) -> str:
    """One printed row: overall successes with the Wilson interval, then per family."""
    k = sum(bool(o.success) for o in outcomes)
    parts = [f"{name:<28} {format_rate(k, len(outcomes))}"]
    parts += [f"family {f}: {s}/{n}" for f, (s, n) in per_family(outcomes, families).items()]
    return "; ".join(parts)


def task_demos(dataset_root: str, repo_id: str, task: str) -> tuple[np.ndarray, list[int], np.ndarray]:
    """``task``'s episodes in an exported dataset (all succeeded in simulation): their commanded plans (N, n), their
    scenes' families (``scene_params["family"]``, -1 where a scene has none) and their importance weights."""
    from prl.features import read_episodes  # heavy: lerobot

    eps = read_episodes(dataset_root, repo_id)
    idx = [i for i, t in enumerate(eps.tasks) if t == task]
    if not idx:
        raise ValueError(f"dataset {dataset_root!r} has no episodes of task {task!r}")
    weights = np.ones(len(eps.tasks)) if eps.weights is None else eps.weights
    return (eps.plan[idx].astype(np.int64), [int(eps.scene_params[i].get("family", -1)) for i in idx],
            np.asarray(weights, dtype=np.float64)[idx])


def family_decodings(plans: Any, families: Sequence[int], weights: Any,
                     prior: Sequence[np.ndarray]) -> dict[int, dict[str, tuple[int, ...]]]:
    """Per family, the plan each RN decoding (``prl.rn_policy.DECODINGS``) would choose if the RN output exactly that
    family's demo marginals: per dimension the importance-weighted share of each choice among the family's demos
    (an RN that reads the family perfectly and nothing finer). Tells a network that fails to read x apart from a
    decoding that cannot express what the demos hold: when these plans fail on their own family's scenes, an RN must
    read more of each scene than its family to do better with that decoding (which scenes each mode works on).

    ``plans`` (N, n) the demos' plans, ``families`` (N,) their scenes' families, ``weights`` (N,) their
    importance weights (prior/proposal, ``prl.proposal``), ``prior`` the task's per-dimension prior (its sizes
    are the dimensions' choices; 'rn_success' divides by it). The library is the distinct demo plans of every
    family, as the RN's (``prl.rn_decode.plan_library``)."""
    from prl.rn_decode import library_plan, plan_library  # heavy: torch

    arr = np.asarray(plans, dtype=np.int64)
    fam = np.asarray(families, dtype=np.int64)
    w = np.asarray(weights, dtype=np.float64)
    dims = [len(q) for q in prior]
    if arr.ndim != 2 or arr.shape[1] != len(dims) or len(arr) < 1:
        raise ValueError(f"plans must have shape (N >= 1, {len(dims)}), got {arr.shape}")
    if fam.shape != (len(arr),) or w.shape != (len(arr),):
        raise ValueError(f"families and weights need one value per plan ({len(arr)}), got shapes {fam.shape} and "
                         f"{w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and >= 0")
    bad = [(i, int(v)) for i, d in enumerate(dims) for v in np.unique(arr[:, i]) if not 0 <= v < d]
    if bad:
        raise ValueError(f"plan choices outside the prior's sizes {dims}: dimension, choice {bad}")
    library = plan_library(arr)
    out: dict[int, dict[str, tuple[int, ...]]] = {}
    for f in sorted(set(fam.tolist())):
        m = fam == f
        if w[m].sum() <= 0:
            raise ValueError(f"family {f}: its demos' weights sum to 0")
        probs = [q[None, :] for q in weighted_choice_freqs(arr[m], dims, w[m])]
        out[f] = {"rn": tuple(int(p.argmax()) for p in probs),
                  "rn_library": tuple(int(v) for v in library_plan(probs, library)[0]),
                  "rn_success": tuple(int(v) for v in library_plan(probs, library, prior)[0])}
    return out


def main(argv: list[str] | None = None) -> int:
    """The family table of one mixed variant on the pipeline's trial scenes (see the module docstring)."""
    summary = " ".join(__doc__.split("\n\n")[0].split())  # the docstring's first paragraph
    parser = argparse.ArgumentParser(prog="python -m envs.families", description=summary)
    parser.add_argument("--task", required=True, help="a mixed variant, e.g. unscrew_mixed")
    parser.add_argument("--scenes", type=int, default=50, help="trial scenes (the pipeline's, run seed --seed)")
    parser.add_argument("--seed", type=int, default=0, help="the run seed the trial scenes derive from")
    parser.add_argument("--dataset-root", default=None, help="an exported dataset: its most frequent demo plans "
                                                              "join the fixed plans")
    parser.add_argument("--repo-id", default=None, help="the dataset's repo id (default: prl/<directory name>)")
    parser.add_argument("--top", type=int, default=20, help="the most frequent demo plans tried")
    parser.add_argument("--decodings", action="store_true",
                        help="with --dataset-root: also each RN decoding of a family-exact RN (the demos' weighted "
                             "marginals of each scene's own family, family_decodings) on the same scenes")
    parser.add_argument("--uniform", action="store_true",
                        help="instead of the family table: the uniformly random plans of `python -m envs.trials "
                             "--kinds uniform` on its --scenes scenes, their successes per family")
    args = parser.parse_args(argv)
    if args.scenes < 1:
        parser.error(f"--scenes must be >= 1, got {args.scenes}")
    if args.top < 1:
        parser.error(f"--top must be >= 1, got {args.top}")
    try:
        plans = family_plans(args.task)
    except ValueError as exc:
        parser.error(str(exc))
    if plans is None:
        parser.error(f"task {args.task!r} has no scene families (no family_expert_plans)")
    if args.decodings and args.dataset_root is None:
        parser.error("--decodings reads the demos: give --dataset-root")
    if args.uniform and args.dataset_root is not None:
        parser.error("--uniform runs the uniform plans instead of the family table: drop --dataset-root")
    if args.dataset_root is not None and not (Path(args.dataset_root) / "meta" / "info.json").is_file():
        parser.error(f"--dataset-root {args.dataset_root!r}: no exported dataset there (meta/info.json missing)")
    from envs.trials import run_trials, trial_scene_seeds  # heavy: loads the simulator

    if args.uniform:
        outs, families = uniform_outcomes(args.task, args.scenes, args.seed)
        print(f"{args.task}: uniform plans on the {args.scenes} scenes of `python -m envs.trials --kinds uniform` "
              f"(families: {dict(sorted(Counter(families).items()))})")
        print(family_line("uniform plans", outs, families))
        return 0
    seeds = trial_scene_seeds(args.seed, args.scenes)
    out = family_outcomes(args.task, seeds)
    families = families_of_oracle(args.task, out["oracle"])
    print(f"{args.task} on {len(seeds)} trial scenes (families: {dict(sorted(Counter(families).items()))})")
    for name, outs in out.items():
        print(family_line(name, outs, families))
    fixed = {f"family {k} expert": out[f"family {k} expert"] for k in plans}
    if args.dataset_root is not None:
        repo_id = args.repo_id or f"prl/{Path(args.dataset_root).name}"
        demos, demo_families, weights = task_demos(args.dataset_root, repo_id, args.task)
        frequent = frequent_plans(demos, args.top)
        known = {tuple(p) for p in plans.values()}
        for plan, count in frequent:
            if plan in known:
                continue
            name = f"demo plan {list(plan)} (x{count})"
            fixed[name] = run_trials(args.task, [plan] * len(seeds), seeds)
            print(family_line(name, fixed[name], families), flush=True)
    best = max(fixed, key=lambda name: sum(bool(o.success) for o in fixed[name]))
    print(f"best single fixed plan of {len(fixed)}: {family_line(best, fixed[best], families)}")
    if args.decodings:
        decoded = family_decodings(demos, demo_families, weights, load_plb().prior(args.task))
        for kind in DECODINGS:
            print(f"family-exact RN, {kind}: " + "; ".join(f"family {f}: {list(d[kind])}" for f, d in decoded.items()))
            plans_run = [decoded[f][kind] if f in decoded else plans[0] for f in families]
            outs = run_trials(args.task, plans_run, seeds)
            print(family_line(f"family-exact RN ({kind})", outs, families), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
