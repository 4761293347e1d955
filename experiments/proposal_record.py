"""The record of a synthesis run's proposal, per task and round, and the check that its weights restore the prior.

Reads only the attempt logs of a finished (or running) synthesis directory (``outputs/synthesis/<key>/``):

* per task and round: attempts, successes, yield with its 95% Wilson interval, demos kept so far, distinct kept
  plans, per-dimension entropy of the kept plans and their effective sample size (``prl.proposal.round_table``);
* the prior-only comparison: round 0 of an adaptive run draws every plan from the prior, so its kept plans are
  a prior-only sample of the same scenes' distribution. Per dimension, the choice frequencies of the later
  rounds' kept plans weighted by prior / proposal are set against round 0's kept plans (unweighted), and their
  raw (unweighted) frequencies are shown too: the weights should bring the first difference under 0.1 where the
  raw one is not (round 0's own sampling error included: with 40 kept plans it is about 0.08 per choice);
* with ``--prior-synthesis-dir D`` (repeatable; synthesis directories of ``--proposal prior`` runs of the same tasks,
  other seeds allowed): Fig 7's means over demos, run against run. Per task and dimension, the largest difference of
  a choice's share between all the kept plans of this run, weighted by prior / proposal (and raw), and the kept plans
  of each prior-only run; and the prior-only runs against each other, the floor two samples of the same size give.

``python -m experiments.proposal_record --synthesis-dir outputs/synthesis/seed0-shards16-frames750-adaptive-r32-s0.5-f0.2
[--prior-synthesis-dir outputs/synthesis/seed0-shards16-frames750-prior ...] [--markdown docs/synthesis_record.md]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from prl.plb import load_plb
from prl.proposal import entropies, round_table, weighted_choice_freqs
from prl.stats import importance_weights


def _rows(synthesis_dir: Path, task: str) -> list[dict]:
    from envs.synthesis import task_attempts  # heavy: loads the simulator

    return task_attempts(synthesis_dir, task)


def task_record(rows: list[dict], sizes: tuple[int, ...]) -> dict:
    """The rounds table and the prior-only comparison of one task's attempt rows."""
    table = round_table(rows, sizes)
    kept = [r for r in rows if r["success"]]
    first = [r for r in kept if int(r.get("round", 0)) == 0]
    later = [r for r in kept if int(r.get("round", 0)) > 0]
    plans = np.array([r["plan"] for r in kept], dtype=np.int64).reshape(-1, len(sizes))
    later_plans, w = kept_plans(later, len(sizes))
    weighted = weighted_choice_freqs(later_plans, sizes, w)
    raw = weighted_choice_freqs(later_plans, sizes)
    prior_only = weighted_choice_freqs(np.array([r["plan"] for r in first], dtype=np.int64).reshape(-1, len(sizes)),
                                       sizes)
    return {"rounds": table, "kept": len(kept), "kept_round0": len(first), "kept_later": len(later),
            "weighted_vs_round0": [float(np.abs(a - b).max()) for a, b in zip(weighted, prior_only)],
            "raw_vs_round0": [float(np.abs(a - b).max()) for a, b in zip(raw, prior_only)],
            "entropy_all": entropies(plans, sizes).tolist(),
            "entropy_round0": entropies(np.array([r["plan"] for r in first]).reshape(-1, len(sizes)), sizes).tolist()}


def kept_plans(rows: list[dict], n_dims: int) -> tuple[np.ndarray, np.ndarray]:
    """The kept (successful) attempts' plans and their weights prior / proposal (mean 1; all 1 in a prior run)."""
    kept = [r for r in rows if r["success"]]
    plans = np.array([r["plan"] for r in kept], dtype=np.int64).reshape(-1, n_dims)
    return plans, importance_weights([r["prior_logp"] for r in kept], [r["proposal_logp"] for r in kept])


def share_gaps(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], sizes: tuple[int, ...],
               weighted: bool = True) -> list[float]:
    """Per dimension, the largest difference of a choice's share between two sets of kept plans (``kept_plans``),
    each counted by its weights (``weighted``) or once per plan."""
    fa, fb = (weighted_choice_freqs(plans, sizes, w if weighted else None) for plans, w in (a, b))
    return [float(np.abs(x - y).max()) for x, y in zip(fa, fb, strict=True)]


def shares_markdown(this: dict[str, tuple[np.ndarray, np.ndarray]],
                    priors: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]], sizes: tuple[int, ...]) -> list[str]:
    """The table of ``share_gaps``: this run's kept plans against each prior-only run's, per task, then the prior-only
    runs against each other (the floor)."""
    def cells(gaps: list[float]) -> str:
        return " ".join(f"{g:.2f}" for g in gaps) + f" (max {max(gaps):.2f})"

    lines = [("Fig 7's means over demos, run against run: per dimension, the largest difference of a choice's share "
              "among the kept plans (this run weighted by prior / proposal, and raw):"), "",
             "| task | kept plans | against (prior-only run, kept plans) | weighted a0..a5 | raw a0..a5 |",
             "|---|---|---|---|---|"]
    names = list(priors)
    for task, mine in this.items():
        for name in names:
            if task in priors[name]:
                theirs = priors[name][task]
                lines.append(f"| {task} | this run, {len(mine[0])} | {name}, {len(theirs[0])} | "
                             f"{cells(share_gaps(mine, theirs, sizes))} | {cells(share_gaps(mine, theirs, sizes, False))} |")
        for i, x in enumerate(names):
            for y in names[i + 1:]:
                if task in priors[x] and task in priors[y]:
                    lines.append(f"| {task} | {x}, {len(priors[x][task][0])} | {y}, {len(priors[y][task][0])} | "
                                 f"{cells(share_gaps(priors[x][task], priors[y][task], sizes))} | - |")
    return lines


def markdown(records: dict[str, dict], synthesis_dir: Path) -> str:
    lines = [f"Synthesis record of `{synthesis_dir.name}` (`python -m experiments.proposal_record`).", ""]
    lines += [("| task | round | attempts | successes | yield (95% CI) | kept so far | distinct kept plans | "
               "entropy a0..a5 (nats) | effective sample size |"), "|---|---|---|---|---|---|---|---|---|"]
    for task, rec in records.items():
        for r in rec["rounds"]:
            lines.append(f"| {task} | {r['round']} | {r['attempts']} | {r['successes']} | {r['yield']:.2f} "
                         f"({r['yield_ci95'][0]:.2f}-{r['yield_ci95'][1]:.2f}) | {r['kept']} | {r['distinct_plans']} | "
                         + " ".join(f"{e:.2f}" for e in r["entropy"]) + f" | {r['ess']:.0f} |")
    lines += ["", ("Per dimension, the largest difference of a choice's frequency between the kept plans of round 0 "
                   "(drawn from the prior) and the kept plans of the later rounds (drawn from the adapted proposal), "
                   "weighted by prior / proposal and raw (unweighted):"), "",
              ("| task | kept (round 0, later) | weighted a0..a5 | raw a0..a5 | entropy a0..a5, round 0 | "
               "entropy, all kept |"),
              "|---|---|---|---|---|---|"]
    for task, rec in records.items():
        lines.append(f"| {task} | {rec['kept']} ({rec['kept_round0']}, {rec['kept_later']}) | "
                     + " ".join(f"{v:.2f}" for v in rec["weighted_vs_round0"]) + " | "
                     + " ".join(f"{v:.2f}" for v in rec["raw_vs_round0"]) + " | "
                     + " ".join(f"{v:.2f}" for v in rec["entropy_round0"]) + " | "
                     + " ".join(f"{v:.2f}" for v in rec["entropy_all"]) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--synthesis-dir", required=True, type=Path)
    parser.add_argument("--prior-synthesis-dir", type=Path, action="append", default=[],
                        help="synthesis directory of a --proposal prior run of the same tasks (repeatable): Fig 7's "
                             "means over demos, run against run")
    parser.add_argument("--markdown", type=Path, default=None, help="also write the tables to this file")
    args = parser.parse_args(argv)
    for d in (args.synthesis_dir, *args.prior_synthesis_dir):
        if not d.is_dir():
            print(f"error: no synthesis directory at {str(d)!r}", file=sys.stderr)
            return 2
    plb = load_plb()
    tasks = sorted(p.name for p in args.synthesis_dir.iterdir() if p.is_dir())
    rows = {t: _rows(args.synthesis_dir, t) for t in tasks}
    records = {t: task_record(r, plb.sizes) for t, r in rows.items()}
    text = markdown(records, args.synthesis_dir)
    if args.prior_synthesis_dir:
        priors = {f"{d.parent.parent.name}: {d.name}": {t: kept_plans(_rows(d, t), len(plb.sizes)) for t in tasks
                                                       if (d / t).is_dir()}
                  for d in args.prior_synthesis_dir}
        text += "\n" + "\n".join(shares_markdown({t: kept_plans(r, len(plb.sizes)) for t, r in rows.items()}, priors,
                                                  plb.sizes)) + "\n"
    print(text)
    if args.markdown:
        args.markdown.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
