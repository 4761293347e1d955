"""Yield of synthesis per proposal setting: the same tasks, demos and seeds, one setting after another.

Each setting runs synthesis bare (``envs.synthesis.synthesize_rounds`` in this process, one core: no trials, no
export, no Prefect) into its own directory under ``--output-dir``, named as the pipeline names it
(``flows.synthesize.synthesis_dir``), so a killed run resumes and a finished one is only read. Printed per task
and setting: attempts, demos kept, yield with its 95% Wilson interval, distinct kept plans, the mean
per-dimension entropy of the kept plans (nats), the weights' effective sample size, and the physics frames per
attempt. Yields do not depend on the machine's load, so settings may run one after another.

``python -m experiments.proposal_yield --tasks tweeze --demos 400 --n-shards 8 --round-attempts 8 --replay 0,0.5``
(``--prior`` adds the prior-only run of the same scenes).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from prl.config import ConfigError, make_config
from prl.stats import wilson_interval


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers separated by commas, got {text!r}") from None


def run_setting(tasks: list[str], demos: int, n_shards: int, out: Path, proposal: str, round_attempts: int,
                smoothing: float, floor: float, defensive: float, replay: float,
                weighted: bool = False) -> dict[str, dict]:
    """Synthesise (or resume, or read) one setting; the record of each task."""
    from envs.synthesis import run_shard, synthesize_rounds, task_attempts  # heavy: loads the simulator
    from experiments.proposal_record import task_record
    from flows.synthesize import shard_specs, synthesis_dir
    from prl.plb import load_plb

    cfg = make_config("paper", tasks=tasks, demos_per_task=demos, n_shards=n_shards, output_dir=str(out),
                      proposal=proposal, round_attempts=round_attempts, proposal_smoothing=smoothing,
                      proposal_floor=floor, proposal_defensive=defensive, proposal_replay=replay,
                      proposal_weighted=weighted)
    where = synthesis_dir(cfg)
    specs = shard_specs(tasks, demos, cfg.seed, n_shards, where, n_frames=cfg.episode_frames)
    synthesize_rounds(specs, cfg.proposal_config(), lambda todo: [run_shard(s, keep_env=True) for s in todo])
    sizes = load_plb().sizes
    out_records = {}
    for task in tasks:
        rows = task_attempts(where, task)
        rec = task_record(rows, sizes)
        rec["frames_per_attempt"] = float(np.mean([r.get("frames", cfg.episode_frames) for r in rows]))
        rec["attempts"] = len(rows)
        rec["dir"] = where.name
        out_records[task] = rec
    return out_records


def table(results: list[tuple[str, dict[str, dict]]]) -> str:
    lines = [("| task | setting | attempts | kept | yield (95% CI) | distinct kept plans | mean entropy (nats) "
             "| effective sample size | frames per attempt |"), "|---|---|---|---|---|---|---|---|---|"]
    tasks = list(dict.fromkeys(t for _, recs in results for t in recs))
    for task in tasks:
        for name, recs in results:
            rec = recs[task]
            lo, hi = wilson_interval(rec["kept"], rec["attempts"])
            last = rec["rounds"][-1]
            lines.append(f"| {task} | {name} | {rec['attempts']} | {rec['kept']} | {rec['kept'] / rec['attempts']:.2f} "
                         f"({lo:.2f}-{hi:.2f}) | {last['distinct_plans']} | {np.mean(rec['entropy_all']):.2f} "
                         f"| {last['ess']:.0f} | {rec['frames_per_attempt']:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default="tweeze", help="tasks, comma-separated")
    parser.add_argument("--demos", type=int, default=400, help="demos kept per task")
    parser.add_argument("--n-shards", type=int, default=8)
    parser.add_argument("--round-attempts", type=int, default=32)
    parser.add_argument("--smoothing", type=float, default=0.5)
    parser.add_argument("--floor", type=float, default=0.2)
    parser.add_argument("--defensive", type=float, default=0.2)
    parser.add_argument("--replay", type=_floats, default=[0.0], help="replay shares to compare, comma-separated")
    parser.add_argument("--weighted", choices=("no", "yes", "both"), default="no",
                        help="count successes by their importance weights in the update and replays (prl.proposal)")
    parser.add_argument("--prior", action="store_true", help="also the prior-only run")
    parser.add_argument("--output-dir", type=Path, default=Path("outputs/experiments/proposal_yield"))
    parser.add_argument("--markdown", type=Path, default=None, help="also write the table to this file")
    args = parser.parse_args(argv)
    tasks = [t for t in args.tasks.split(",") if t]
    settings = [("prior", "prior", 0.0, False)] if args.prior else []
    weightings = {"no": [False], "yes": [True], "both": [False, True]}[args.weighted]
    settings += [((f"adaptive r{args.round_attempts} s{args.smoothing:g} f{args.floor:g} d{args.defensive:g} "
                  f"x{x:g}" + (" w" if w else "")), "adaptive", x, w) for x in args.replay for w in weightings]
    results = []
    try:
        for name, kind, replay, weighted in settings:
            print(f"[proposal_yield] {name}", file=sys.stderr, flush=True)
            results.append((name, run_setting(tasks, args.demos, args.n_shards, args.output_dir, kind,
                                              args.round_attempts, args.smoothing, args.floor, args.defensive,
                                              replay, weighted)))
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    text = table(results)
    print(text)
    if args.markdown:
        args.markdown.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
