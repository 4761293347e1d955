"""One-time migration of the committed LN summaries to outcome versions per method (``prl.version``).

Before it, a summary's ``code_version`` covered one file list for every method, the joint-control environment and
the export's schema included, so editing either would have made every point stale. This script:

1. checks that each summary in ``docs/results/ln`` was made under the ``--base`` commit's files: its recorded
   ``code_version`` equals the former scheme's digest (``FORMER_SHARED_FILES``) of that commit's bytes;
2. re-runs ``--check-episodes`` evaluation episodes of each task (their scene seeds and plans, from the task's
   plan-space summaries) and requires the recorded success (the outcome the summaries count; the measures are
   printed beside the recorded ones: PhysX on the CPU repeats itself on one machine, not across machines, and
   the summaries were made on others);
3. records ``code_files`` and ``code_version`` of the new scheme: for plan-space points and the reference rows from
   the working tree (nothing that decides their outcomes changed, which step 2 checks), for joint-space points from
   the base commit's bytes (what they ran on), so the report names the files that changed since.

    python scripts/migrate_outcome_versions.py --base <commit> [--check-episodes 4] [--dry-run]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from prl.constants import REPO_ROOT
from prl.ln_summary import summary_bytes
from prl.version import (
    OUTCOME_ASSET_SUFFIXES,
    PLB_CATALOGUE,
    _task_modules,
    catalogue_view,
    method_family,
    outcome_file_digests,
    version_of,
)

FORMER_SHARED_FILES = (
    "envs/__init__.py", "envs/agents/__init__.py", "envs/agents/prl_hand.py", "envs/hand_model.py", "envs/ik.py",
    "envs/sensors.py", "envs/tasks/__init__.py", "envs/tasks/base.py", "envs/executor.py", "envs/execution.py",
    "envs/episode.py", "envs/scene_record.py", "envs/scene_stream.py", "envs/plan_env.py", "envs/joint_env.py",
    "envs/vec_env.py", "envs/trials.py", "envs/reach.py",
    "prl/__init__.py", "prl/ln.py", "prl/features.py", "prl/demo.py", "prl/pointnet.py", "prl/rn.py",
    "prl/text_embed.py", "prl/shapes.py", "prl/plb.py", "prl/constants.py", "prl/geometry.py", "prl/labels.py",
    "prl/stages.py", "prl/atomic.py", "prl/export_schema.py", "prl/export_check.py", "prl/dataset_files.py",
    "prl/stats.py",
)
"""The former scheme's shared file list (every task, every method)."""


def git_bytes(commit: str, rel: str) -> bytes | None:
    """``rel``'s bytes at ``commit``, None where it did not exist."""
    res = subprocess.run(["git", "show", f"{commit}:{rel}"], cwd=REPO_ROOT, capture_output=True, check=False)
    return res.stdout if res.returncode == 0 else None


def former_version(task: str, commit: str) -> str:
    """The former ``outcome_version(task)`` of ``commit``'s files (its task modules as the working tree imports
    them, its assets as listed in that commit)."""
    listed = subprocess.run(["git", "ls-tree", "-r", "--name-only", commit, "assets"], cwd=REPO_ROOT,
                            capture_output=True, text=True, check=True).stdout.split()
    assets = [rel for rel in listed if Path(rel).suffix in OUTCOME_ASSET_SUFFIXES]
    files = sorted({*_task_modules(f"envs/tasks/{task}.py"), *FORMER_SHARED_FILES, *assets})
    h = hashlib.sha256()
    for rel in files:
        data = git_bytes(commit, rel)
        if data is None:
            raise FileNotFoundError(f"{rel} is not in commit {commit}")
        h.update(rel.encode())
        h.update(catalogue_view(data, task) if rel == PLB_CATALOGUE else data)
    return h.hexdigest()[:16]


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
    parser.add_argument("--base", required=True, help="the commit the summaries were made under")
    parser.add_argument("--results-dir", type=Path, default=REPO_ROOT / "docs/results/ln")
    parser.add_argument("--check-episodes", type=int, default=4, help="episodes re-run per task")
    parser.add_argument("--dry-run", action="store_true")
    args = parser.parse_args()
    paths = sorted(args.results_dir.glob("*.json"))
    summaries = {p: json.loads(p.read_text()) for p in paths}
    former: dict[str, str] = {}
    for path, s in summaries.items():
        task = s["point"]["task"] if "point" in s else s["task"]
        former.setdefault(task, former_version(task, args.base))
        if s["code_version"] != former[task]:
            raise SystemExit(f"{path.name} records {s['code_version']}, not the {args.base} files' {former[task]}: "
                             f"it was not made under that commit; nothing migrated")
    print(f"{len(summaries)} summaries were made under {args.base}")
    check_episodes(summaries, args.check_episodes)
    for path, s in summaries.items():
        task = s["point"]["task"] if "point" in s else s["task"]
        method = s["point"]["method"] if "point" in s else "reference"
        read = None if method_family(method) == "plan" else (lambda rel: git_bytes(args.base, rel))
        files = outcome_file_digests(task, method, read=read)
        s.update(code_files=files, code_version=version_of(files))
        if not args.dry_run:
            path.write_bytes(summary_bytes(s))
        print(f"{path.name}: {method_family(method)} -> {s['code_version']}")


if __name__ == "__main__":
    main()
