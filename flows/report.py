"""The LN results report: ``python -m flows.report`` makes ``docs/results.md`` and its Fig 8 per task
(``docs/results/fig8_<task>_timesteps.png``, ``..._frames.png``) from the committed point summaries in
``docs/results/ln/*.json`` alone (``prl.report``): no MLflow store, no ``outputs/``. The same summaries give the same
bytes. Each task's table also shows the reference plans of ``reference-<task>.json`` (the expert plan, a prior-sampled
plan and the RN's argmax plan on the points' evaluation scenes), written by ``python -m flows.ln_reference --tasks
hammer,sweep,unscrew,tweeze [--eval-seed 0] [--eval-scenes 50] [--rn-path P]``. A missing or empty summaries directory, or a malformed summary, is an error naming it (exit status 2).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import envs.tasks  # noqa: F401  (declares every task: the report names their measures' units)
from prl.constants import REPO_ROOT
from prl.ln_summary import SummaryError
from prl.report import write_report

RESULTS_DIR = REPO_ROOT / "docs" / "results" / "ln"
"""The committed point summaries (written by ``python -m flows.ablation ... --results-dir docs/results/ln``)."""
REPORT = REPO_ROOT / "docs" / "results.md"
"""The generated report."""
FIGURES_DIR = REPO_ROOT / "docs" / "results"
"""Where the report's figures go."""


def cli_parser() -> argparse.ArgumentParser:
    """The report's command line (defaults: the committed summaries, ``docs/results.md``, ``docs/results/``)."""
    parser = argparse.ArgumentParser(prog="python -m flows.report", description=__doc__.splitlines()[0])
    parser.add_argument("--results-dir", type=Path, default=RESULTS_DIR, help="the point summaries (*.json)")
    parser.add_argument("--out", type=Path, default=REPORT, help="the markdown report to write")
    parser.add_argument("--figures-dir", type=Path, default=FIGURES_DIR, help="where the figures go")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = cli_parser().parse_args(argv)
    try:
        written = write_report(args.results_dir, args.out, args.figures_dir)
    except (FileNotFoundError, SummaryError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print("\n".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
