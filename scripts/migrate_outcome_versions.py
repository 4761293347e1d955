"""Re-record the committed LN summaries' outcome versions after a change of the version scheme (``prl.version``),
checked, so that no point goes stale through a change that decides no outcome.

A change to how versions are computed (which files a task's version covers, how the catalogue is cut per task) or
to a shared file that moves code without changing what it computes (the task registry) gives every point a new
version. This script:

1. asks the ``--base`` commit (checked out in a temporary git worktree, with its own ``prl.version``) which
   summaries in ``docs/results/ln`` were current there: only those are re-recorded (a point stale at the base
   stays stale);
2. re-runs ``--check-episodes`` evaluation episodes of each task (their scene seeds and plans, from the task's
   plan-space summaries) with the working tree's code and requires the recorded success (the outcome the summaries
   count; the measures are printed beside the recorded ones: PhysX on the CPU repeats itself on one machine, not
   across machines, and the summaries were made on others);
3. records ``code_files`` and ``code_version`` of the working tree for each summary current at the base.

    python scripts/migrate_outcome_versions.py --base <commit> [--check-episodes 4] [--dry-run]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from prl.constants import REPO_ROOT
from prl.ln_summary import summary_bytes
from prl.version import method_family, outcome_file_digests, version_of

CURRENT_AT = """
import json, sys
from pathlib import Path
from prl.ln_summary import read_summaries, stale_points
from prl.ln_reference import read_references, reference_file_name
d = Path(sys.argv[1])
all_ = {**read_summaries(d), **{reference_file_name(t).removesuffix(".json"): r for t, r in read_references(d).items()}}
stale = stale_points(all_)
print(json.dumps(sorted(n for n in all_ if n not in stale)))
"""
"""Run in the base commit's worktree: the names of the summaries current there."""


def current_at(commit: str, results_dir: Path) -> set[str]:
    """The names (file stems) of the summaries of ``results_dir`` whose version is current at ``commit``, as that
    commit's own ``prl.version`` computes it."""
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "base"
        subprocess.run(["git", "worktree", "add", "--detach", str(tree), commit], cwd=REPO_ROOT, check=True,
                       capture_output=True)
        try:
            out = subprocess.run([sys.executable, "-c", CURRENT_AT, str(results_dir.resolve())], cwd=tree,
                                 check=True, capture_output=True, text=True,
                                 env={**os.environ, "PYTHONPATH": str(tree)}).stdout
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=REPO_ROOT, check=False)
    return set(json.loads(out.strip().splitlines()[-1]))


def check_episodes(summaries: dict[Path, dict], per_task: int) -> None:
    """Re-run ``per_task`` recorded evaluation episodes per task of the plan-space summaries; SystemExit on any
    success that differs."""
    from envs.trials import run_policy  # heavy: loads the simulator

    by_task: dict[str, list[tuple[int, list[int], bool, float, int]]] = {}
    for s in summaries.values():
        task = s["point"]["task"] if "point" in s else s["task"]
        if "point" not in s or method_family(s["point"]["method"]) != "plan":
            continue
        picks = by_task.setdefault(task, [])
        n_frames = int(s["settings"].get("n_frames", 750))
        for o in s["eval"]["outcomes"]:
            if len(picks) < per_task and not o.get("error") and o["seed"] not in {p[0] for p in picks}:
                picks.append((int(o["seed"]), list(o["plan"]), bool(o["success"]), float(o["measure"]), n_frames))
                break  # one episode per summary, so the picks span several points
    bad = []
    for task, picks in sorted(by_task.items()):
        plans = [p[1] for p in picks]
        got = run_policy(task, lambda i, env, x, plans=plans: plans[i], [p[0] for p in picks], n_frames=picks[0][4],
                         progress=False)
        for (seed, plan, success, measure, _), o in zip(picks, got, strict=True):
            same = o.success == success
            print(f"{task} seed {seed} plan {plan}: recorded {success} (measure {measure:.4f}), now {o.success} "
                  f"({o.measure:.4f}) {'ok' if same else 'DIFFERS'}")
            if not same:
                bad.append(f"{task} seed {seed}")
    if bad:
        raise SystemExit(f"recorded outcomes not reproduced: {', '.join(bad)}; nothing migrated")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base", required=True, help="the commit whose versions the summaries were current under")
    parser.add_argument("--results-dir", type=Path, default=REPO_ROOT / "docs/results/ln")
    parser.add_argument("--check-episodes", type=int, default=4, help="episodes re-run per task")
    parser.add_argument("--dry-run", action="store_true")
    args = parser.parse_args()
    summaries = {p: json.loads(p.read_text()) for p in sorted(args.results_dir.glob("*.json"))}
    current = current_at(args.base, args.results_dir)
    print(f"{len(current)} of {len(summaries)} summaries are current at {args.base}")
    check_episodes({p: s for p, s in summaries.items() if p.stem in current}, args.check_episodes)
    for path, s in summaries.items():
        if path.stem not in current:
            print(f"{path.name}: stale at {args.base}, left as it is")
            continue
        task = s["point"]["task"] if "point" in s else s["task"]
        method = s["point"]["method"] if "point" in s else "reference"
        files = outcome_file_digests(task, method)
        s.update(code_files=files, code_version=version_of(files))
        if not args.dry_run:
            path.write_bytes(summary_bytes(s))
        print(f"{path.name}: {method_family(method)} -> {s['code_version']}")


if __name__ == "__main__":
    main()
