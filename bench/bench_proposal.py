"""The record of a synthesis run's proposal, per task and round, and the check that its weights restore the prior.

Reads only the attempt logs of a finished (or running) synthesis directory (``outputs/synthesis/<key>/``):

* per task and round: attempts, successes, yield with its 95% Wilson interval, demos kept so far, distinct kept
  plans, per-dimension entropy of the kept plans and their effective sample size (``prl.proposal.round_table``);
* the prior-only comparison: round 0 of an adaptive run draws every plan from the prior, so its kept plans are
  a prior-only sample of the same scenes' distribution. Per dimension, the choice frequencies of the later
  rounds' kept plans weighted by prior / proposal are set against round 0's kept plans (unweighted), and their
  raw (unweighted) frequencies are shown too: the weights should bring the first difference under 0.1 where the
  raw one is not (round 0's own sampling error included: with 40 kept plans it is about 0.08 per choice).

``python -m bench.bench_proposal --synthesis-dir outputs/synthesis/seed0-shards16-frames750-adaptive-r32-s0.5-f0.2
[--markdown docs/synthesis_record.md]``
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
    later_plans = np.array([r["plan"] for r in later], dtype=np.int64).reshape(-1, len(sizes))
    w = importance_weights([r["prior_logp"] for r in later], [r["proposal_logp"] for r in later]) if later else []
    weighted = weighted_choice_freqs(later_plans, sizes, w)
    raw = weighted_choice_freqs(later_plans, sizes)
    prior_only = weighted_choice_freqs(np.array([r["plan"] for r in first], dtype=np.int64).reshape(-1, len(sizes)),
                                       sizes)
    return {"rounds": table, "kept": len(kept), "kept_round0": len(first), "kept_later": len(later),
            "weighted_vs_round0": [float(np.abs(a - b).max()) for a, b in zip(weighted, prior_only)],
            "raw_vs_round0": [float(np.abs(a - b).max()) for a, b in zip(raw, prior_only)],
            "entropy_all": entropies(plans, sizes).tolist(),
            "entropy_round0": entropies(np.array([r["plan"] for r in first]).reshape(-1, len(sizes)), sizes).tolist()}


def markdown(records: dict[str, dict], synthesis_dir: Path) -> str:
    lines = [f"Synthesis record of `{synthesis_dir.name}` (`python -m bench.bench_proposal`).", ""]
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
    parser.add_argument("--markdown", type=Path, default=None, help="also write the tables to this file")
    args = parser.parse_args(argv)
    if not args.synthesis_dir.is_dir():
        print(f"error: no synthesis directory at {str(args.synthesis_dir)!r}", file=sys.stderr)
        return 2
    plb = load_plb()
    tasks = sorted(p.name for p in args.synthesis_dir.iterdir() if p.is_dir())
    records = {t: task_record(_rows(args.synthesis_dir, t), plb.sizes) for t in tasks}
    text = markdown(records, args.synthesis_dir)
    print(text)
    if args.markdown:
        args.markdown.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
