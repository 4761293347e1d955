"""The LN results report, ``docs/results.md`` and its Fig 8 per task, made from the committed point summaries alone
(``prl.ln_summary``; ``python -m flows.report``): no MLflow store, no ``outputs/``.

Per task and method (a group: task, method, K, timesteps) the final plan's success on the evaluation scenes,
pooled over seeds with its Wilson interval and per seed; the interquartile mean of the seeds' success fractions
with a stratified-bootstrap interval over seeds and scenes, and the probability that K = 1,280 beats K = 0 and
beats BC (``prl.robust_stats``, rliable's method); the curves' first and last window success; whether the reward
ranks successes above failures (``reward_table``); the compute; the
provenance (code versions, dataset digests); and what of the planned experiment (``planned_points``) is missing.
Beside each task's methods, the reference plans of ``reference-<task>.json`` (``prl.ln_reference``, written by
``python -m flows.ln_reference``: the expert plan, a prior-sampled plan and the RN's argmax plan on the points'
evaluation scenes), with a flag when their scenes or code version are not the points'. A summary whose recorded code
version is not today's (``stale_points``: ``prl.version.outcome_version`` of its task and method) is left out of
every table and figure and listed apart with the files that changed. The same summaries give the
same bytes: no clock, fixed bootstrap seed, sorted orders, PNGs without the
matplotlib version.
"""

from __future__ import annotations

import datetime
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from prl.atomic import write_atomic
from prl.config import JOINT_A2C_METHODS, PAPER_LN_DEMO_STEPS
from prl.constants import REPO_ROOT, TASKS
from prl.ln_reference import read_references, reference_file_name, reference_note, reference_rows
from prl.ln_summary import rate_cell, read_summaries, stale_points, stale_section
from prl.report_points import (
    GATED_VARIANTS,
    HAMMER_EXTRA_K,
    JOINT_FRAMES_PER_STEP,
    PAPER_TIMESTEPS,
    PLAN_SEEDS,
    PLANNED_VARIANTS,
    Group,
    equal_frames_budget,
    group_of,
    grouped,
    missing_points,
    planned_points,
)
from prl.robust_stats import probability_of_improvement, stratified_bootstrap_ci
from prl.task_registry import declared, units_text
from prl.version import JOINT_METHODS

BOOTSTRAP_REPS = 10_000
"""Bootstrap draws of every interval of the report."""
BOOTSTRAP_SEED = 0
"""The seed of every bootstrap of the report (the same summaries give the same intervals)."""
TARGET = 0.9
"""The issue's target: K = 1,280's final plan success pooled over seeds, on every task."""
VARIANT_TARGET = 0.85
"""A task variant's target (issue #26): the LN pre-trained on the variant's demos, pooled over seeds."""
COMMAND = "python -m flows.report"
"""The command that makes the report."""


def _runs(members: Sequence[Mapping[str, Any]]) -> list[list[float]]:
    return [[float(o["success"]) for o in s["eval"]["outcomes"]] for s in members]


def _pooled(members: Sequence[Mapping[str, Any]]) -> tuple[int, int]:
    """Successes and scenes of ``members``' final evaluations together."""
    return sum(s["eval"]["successes"] for s in members), sum(s["eval"]["n"] for s in members)


def _ci(estimate: float, lo: float, hi: float) -> str:
    return f"{estimate:.2f} ({lo:.2f}-{hi:.2f})"


def _window(members: Sequence[Mapping[str, Any]]) -> str:
    parts = [f"{s['rows'][0]['window_success_rate']:.2f} -> {s['rows'][-1]['window_success_rate']:.2f}"
             if s["rows"] else f"loss {s['loss'][0]['loss']:.3f} -> {s['loss'][-1]['loss']:.3f}"
             if s.get("loss") else "no update" for s in members]
    return ", ".join(parts)


def _iqm_cell(runs: Mapping[str, list[list[float]]]) -> str:
    if not all(r for rs in runs.values() for r in rs):
        return "-"
    return _ci(*stratified_bootstrap_ci(runs, reps=BOOTSTRAP_REPS, seed=BOOTSTRAP_SEED))


def _poi(x: Mapping[str, list[list[float]]], y: Mapping[str, list[list[float]]]) -> tuple[float, float, float] | None:
    if not x or not all(r for rs in [*x.values(), *y.values()] for r in rs):
        return None
    return probability_of_improvement(x, y, reps=BOOTSTRAP_REPS, seed=BOOTSTRAP_SEED)


SUCCESS_HEADER = ("| method | seeds | per seed | pooled (95% Wilson CI) | IQM (95% bootstrap CI) "
                  "| training window success, first -> last update |")
"""The header of a task's table of final success."""


def _task_order(task: str) -> tuple[int, str]:
    return (TASKS.index(task) if task in TASKS else len(TASKS), task)


def success_tables(groups: Mapping[Group, Sequence[Mapping[str, Any]]],
                   references: Mapping[str, Mapping[str, Any]] | None = None) -> list[str]:
    """Per task, a table of its groups' final success (see the module docstring) and its reference plans' rows
    (``references`` by task), and the target's verdict."""
    lines: list[str] = []
    references = references or {}
    for task in sorted({*(g.task for g in groups), *references}, key=_task_order):
        lines += [f"### {task}", "", SUCCESS_HEADER, "|---|---|---|---|---|---|"]
        for g, members in groups.items():
            if g.task != task:
                continue
            k, n = _pooled(members)
            per_seed = ", ".join(f"{s['eval']['successes']}/{s['eval']['n']}" for s in members)
            seeds = ",".join(str(s["point"]["seed"]) for s in members)
            lines.append(f"| {g.label} | {seeds} | {per_seed} | {rate_cell(k, n)} | {_iqm_cell({task: _runs(members)})} "
                         f"| {_window(members)} |")
        if task in references:
            lines += reference_rows(references[task])
            lines += ["", reference_note(references[task], [s for g, m in groups.items() if g.task == task
                                                             for s in m])]
        lines += ["", target_line(task, groups, references.get(task)), ""]
    return lines


def target_line(task: str, groups: Mapping[Group, Sequence[Mapping[str, Any]]],
                ref: Mapping[str, Any] | None = None) -> str:
    """The target's verdict of one task: a paper task's LN pre-trained on K = 1,280 demonstration steps pooled >=
    ``TARGET``; a task variant's (``<task>_mixed``) LN pre-trained on its demos (the largest K run) >=
    ``VARIANT_TARGET``, with the paper's reward or, beside it, with the reward paid on success (``physics_gated``),
    and its RN's argmax plan (``ref``'s) >= ``VARIANT_TARGET``."""
    physics = {g.demo_steps: m for g, m in groups.items() if g.task == task and g.method == "physics"
               and g.timesteps == PAPER_TIMESTEPS and g.demo_steps > 0}
    if task in TASKS:
        k = PAPER_LN_DEMO_STEPS
        head, target, members = f"physics K = {k:,}", TARGET, physics.get(k)
    else:
        k = max(physics, default=None)
        head = f"a task variant, physics pre-trained on its demos{f' (K = {k:,})' if k else ''}"
        target, members = VARIANT_TARGET, physics.get(k)
    rn = ""
    if task not in TASKS and ref and "rn" in ref["plans"]:
        won, n = ref["plans"]["rn"]["successes"], ref["plans"]["rn"]["n"]
        rn = f" The RN argmax plan (reference): {rate_cell(won, n)}, {'met' if won / n >= target else '**missed**'}."
    if not members:
        return f"Target ({head}, pooled >= {target:.2f}): not run yet.{rn}"
    won, n = _pooled(members)
    verdict = "met" if n and won / n >= target else "**missed**"
    line = (f"Target ({head}, pooled >= {target:.2f}): {verdict} ({won}/{n} over {len(members)} "
            f"seed{'s' if len(members) != 1 else ''}).")
    gated = [s for g, m in groups.items() if g.task == task and g.method == "physics_gated"
             and g.timesteps == PAPER_TIMESTEPS and g.demo_steps == k for s in m]
    if gated:  # beside the target's verdict, never in its place: the reward is not the paper's
        won, n = _pooled(gated)
        met = f" ({'met' if won / n >= target else '**missed**'})" if task not in TASKS and n else ""
        line += (f" With the reward paid only on success (physics_gated, the same K; not the paper's reward): "
                 f"{rate_cell(won, n)} over {len(gated)} seed{'s' if len(gated) != 1 else ''}{met}.")
    return line + rn


def across_tasks_table(groups: Mapping[Group, Sequence[Mapping[str, Any]]]) -> list[str]:
    """Per method at the paper's budget, the IQM over every task's seeds, stratified by task: the paper's tasks
    (``prl.constants.TASKS``) and the task variants (``hammer_mixed``, ...) apart, so that a variant's scenes never
    move a paper task's number."""
    by_method: dict[tuple[int, str, int, bool], dict[str, list[list[float]]]] = {}
    for g, members in groups.items():
        if g.at_planned_budget:
            key = (g.method_index, g.method, g.demo_steps, g.task not in TASKS)
            by_method.setdefault(key, {})[g.task] = _runs(members)
    lines = ["| method | tasks | IQM over all seeds (95% stratified-bootstrap CI) |", "|---|---|---|"]
    for (_, method, k, _), runs in sorted(by_method.items(), key=lambda kv: (kv[0][3], kv[0][:3])):
        label = Group(0, "", 0, method, k, PAPER_TIMESTEPS).label
        lines.append(f"| {label} | {', '.join(runs)} | {_iqm_cell(runs)} |")
    return lines


def improvement_table(groups: Mapping[Group, Sequence[Mapping[str, Any]]]) -> list[str]:
    """P(physics K = 1,280 > physics K = 0), P(physics K = 1,280 > BC K = 1,280) and, where they ran, P(physics K =
    1,280 > imitation K = 1,280) and P(physics K = 1,280 > joint_bc K = 1,280), per task that has either pair, over
    the paper's tasks that have both and over the variants that have both, each at its planned budget
    (``Group.at_planned_budget``); then per task the comparisons whose interval leaves out 0.5 (resolved) and those
    whose interval holds it."""
    def runs_of(method: str, k: int) -> dict[str, list[list[float]]]:
        return {g.task: _runs(m) for g, m in groups.items()
                if g.method == method and g.demo_steps == k and g.at_planned_budget}

    ref = runs_of("physics", PAPER_LN_DEMO_STEPS)
    compared = [(f"P(physics K={PAPER_LN_DEMO_STEPS} > {m} K={k})", runs_of(m, k))
                for m, k in (("physics", 0), ("bc", PAPER_LN_DEMO_STEPS), ("imitation", PAPER_LN_DEMO_STEPS),
                             ("joint_bc", PAPER_LN_DEMO_STEPS))]
    compared = [(name, runs) for i, (name, runs) in enumerate(compared) if i < 2 or runs]
    others = [runs for _, runs in compared]
    tasks = [t for t in dict.fromkeys(g.task for g in groups) if t in ref and any(t in o for o in others)]
    lines = [f"| comparison | {' | '.join(tasks)} | paper tasks with both | variants with both |",
             "|---|" + "---|" * (len(tasks) + 2)]
    verdicts: dict[str, dict[str, list[str]]] = {t: {"resolved": [], "not resolved": []} for t in tasks}
    for name, other in compared:
        per_task = {t: _poi({t: ref[t]}, {t: other[t]}) if t in other else None for t in tasks}
        pooled = []
        for paper in (True, False):  # the paper's tasks, then the variants: never pooled together
            both = [t for t in tasks if t in other and (t in TASKS) == paper]
            pooled.append(_poi({t: ref[t] for t in both}, {t: other[t] for t in both}) if both else None)
        lines.append(f"| {name} | {' | '.join(_ci(*p) if p else '-' for p in [*per_task.values(), *pooled])} |")
        for t, p in per_task.items():
            if p:  # resolved when the interval of P(A > B) leaves out 0.5, the coin flip
                verdicts[t]["not resolved" if p[1] <= 0.5 <= p[2] else "resolved"].append(f"{name} = {_ci(*p)}")
    bullets = [f"- {t}: " + "; ".join(f"{k}: {', '.join(v)}" for k, v in kinds.items() if v) for t, kinds in
               verdicts.items() if any(kinds.values())]
    head = "Per task, which comparisons the 95% interval resolves (it leaves out 0.5) and which it does not:"
    return lines + (["", head, "", *bullets] if bullets else [])


def _measure(outcome: Mapping[str, Any]) -> float | None:
    m = outcome.get("measure")
    return float(m) if isinstance(m, (int, float)) and not isinstance(m, bool) and np.isfinite(m) else None


def reward_table(groups: Mapping[Group, Sequence[Mapping[str, Any]]]) -> list[str]:
    """Per task, whether the reward the LN learns from (the task's measure, each final evaluation's ``measure``)
    ranks the successes above the failures: the failures paid at least as much as the least-paid success, with the
    groups and seeds they came from. Outcomes without a finite measure are left out."""
    header = ("| task | scenes | successes | least reward of a success | highest reward of a failure | failures paid at "
              "least the least-paid success | from (method, seed: failures) |")
    lines = [header, "|---|---|---|---|---|---|---|"]
    for task in sorted({g.task for g in groups}, key=_task_order):
        scored = [(g.label, s["point"]["seed"], bool(o["success"]), m) for g, members in groups.items()
                  if g.task == task for s in members for o in s["eval"]["outcomes"]
                  if (m := _measure(o)) is not None]
        won = [m for *_, ok, m in scored if ok]
        lost = [m for *_, ok, m in scored if not ok]
        floor = min(won, default=None)
        paid: dict[tuple[str, int], int] = {}
        for label, seed, ok, m in scored:
            if not ok and floor is not None and m >= floor:
                paid[(label, seed)] = paid.get((label, seed), 0) + 1
        where = ", ".join(f"{label} s{seed}: {n}" for (label, seed), n in paid.items()) or "-"
        lines.append(f"| {task} | {len(scored)} | {len(won)} | {'-' if floor is None else f'{floor:.2f}'} "
                     f"| {f'{max(lost):.2f}' if lost else '-'} | {sum(paid.values()) if floor is not None else '-'} "
                     f"| {where} |")
    return lines


def _hours(summary: Mapping[str, Any]) -> float:
    start = datetime.datetime.fromisoformat(summary["started"])
    end = datetime.datetime.fromisoformat(summary["finished"])
    return max(0.0, (end - start).total_seconds() / 3600.0)


def elapsed_hours(summaries: Sequence[Mapping[str, Any]]) -> float:
    """Hours during which at least one point ran (the union of the points' start-finish intervals)."""
    spans = sorted((datetime.datetime.fromisoformat(s["started"]), datetime.datetime.fromisoformat(s["finished"]))
                   for s in summaries)
    total, current = 0.0, None
    for start, end in spans:
        if current is None or start > current[1]:
            if current is not None:
                total += (current[1] - current[0]).total_seconds()
            current = [start, end]
        else:
            current[1] = max(current[1], end)
    if current is not None:
        total += (current[1] - current[0]).total_seconds()
    return total / 3600.0


def compute_table(summaries: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Per task, per method and in all: points, their wall time and core-hours (``cores`` x start-finish), train and
    evaluation hours; then the elapsed time and the dates."""
    rows: dict[str, list[Mapping[str, Any]]] = {}
    methods: dict[str, list[Mapping[str, Any]]] = {}
    for s in sorted(summaries.values(), key=lambda s: group_of(s)):
        rows.setdefault(s["point"]["task"], []).append(s)
    for s in sorted(summaries.values(), key=lambda s: (group_of(s).method_index, group_of(s))):
        methods.setdefault(f"method: {group_of(s).method}", []).append(s)
    everything = [s for members in rows.values() for s in members]
    lines = ["| task or method | points | wall time, summed over points (h) | core-hours | training (h) | evaluation (h) |",
             "|---|---|---|---|---|---|"]
    for name, members in [*rows.items(), *methods.items(), ("all", everything)]:
        wall = sum(_hours(s) for s in members)
        cores = sum(s["cores"] * _hours(s) for s in members)
        train = sum(s["train_seconds"] for s in members) / 3600.0
        ev = sum(s["eval_seconds"] for s in members) / 3600.0
        lines.append(f"| {name} | {len(members)} | {wall:.1f} | {cores:.1f} | {train:.1f} | {ev:.1f} |")
    if not everything:
        return lines
    first = min(s["started"] for s in everything)
    last = max(s["finished"] for s in everything)
    lines += ["", (f"The points ran between {first} and {last} (UTC); at least one point was running during "
                  f"{elapsed_hours(everything):.1f} h of that (points run side by side, so this is less than the "
                  f"summed wall time). `cores` is what a point keeps busy: 1 with one plan environment, else one "
                  f"per environment plus the main process.")]
    return lines


def provenance_table(summaries: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Per task, the code versions and dataset digests of its points (each with its count), and the settings
    whose values differ between points of the report (beyond the point's own)."""
    by_task: dict[str, list[Mapping[str, Any]]] = {}
    for s in sorted(summaries.values(), key=lambda s: group_of(s)):
        by_task.setdefault(s["point"]["task"], []).append(s)

    def counted(values: list[Any]) -> str:
        return ", ".join(f"`{v}` ({values.count(v)})" for v in sorted(set(values), key=str))

    lines = ["| task | code versions (points) | dataset digests (points; joint control: none) |", "|---|---|---|"]
    for task, members in by_task.items():
        digests = [s["dataset_digest"] for s in members if s["dataset_digest"] is not None]
        lines.append(f"| {task} | {counted([s['code_version'] for s in members])} | {counted(digests) or '-'} |")
    per_point = {"ln.demo_steps", "ln.seed", "ln.pretrain_mode", "ln.timesteps"}
    keys = sorted({k for s in summaries.values() for k in s["settings"]} - per_point)
    varying = [k for k in keys if len({repr(s["settings"].get(k)) for s in summaries.values()
                                       if k in s["settings"]}) > 1]
    lines += ["", "Settings that differ between points (beyond K, seed, pre-training mode and timesteps): "
              + (", ".join(f"`{k}`" for k in varying) if varying else "none") + "."]
    return lines


def missing_section(summaries: Mapping[str, Mapping[str, Any]], groups: Mapping[Group, Sequence[Any]],
                    results_rel: str) -> list[str]:
    """The planned points without a summary, per task, and the commands that run them."""
    plan = planned_points()
    missing = missing_points(summaries, plan)
    lines = [f"{len(plan) - len(missing)} of the {len(plan)} planned points are done."]
    if not missing:
        return lines
    lines += ["", "| task | missing points: method, seeds |", "|---|---|"]
    for task in dict.fromkeys(p.task for p in missing):
        arms: dict[str, list[str]] = {}
        for p in missing:
            if p.task == task:
                arm = Group(0, task, 0, p.method, p.demo_steps, PAPER_TIMESTEPS).label
                arm += " at equal frames" if p.equal_frames else ""
                arms.setdefault(arm, []).append(str(p.seed))
        lines.append(f"| {task} | {'; '.join(f'{arm}: {",".join(seeds)}' for arm, seeds in arms.items())} |")
    budgets = [f"{t}: {b:,}" if (b := equal_frames_budget(groups, t)) else f"{t}: after its K = 1,280 runs"
               for t in dict.fromkeys(p.task for p in missing if p.equal_frames)]
    seeds, tail = ",".join(map(str, PLAN_SEEDS)), f"--results-dir {results_rel}"
    if any(p.task not in PLANNED_VARIANTS for p in missing):
        lines += ["", "They are run by (D: the paper-profile dataset and its PointNet, `--dataset-root ... "
                      + "--pointnet-path ...`, which joint control alone does not need; the committed points' demos are "
                      + "those of `python -m flows.full_pipeline --profile paper --proposal-defensive 0`, the synthesis "
                      + "recipe their summaries name; imitation reads its "
                      + "`observation.environment_state`, which a dataset exported before it lacks; an `--output-dir` of each "
                      + "command's own; the hammer's K = 2,560 needs a dataset with at least 2,560 hammer demos):",
                  "", "```",
                  f"python -m flows.ablation $D --tasks {','.join(TASKS)} --methods physics,bc,joint --demo-steps "
                  + f"0,{PAPER_LN_DEMO_STEPS} --seeds {seeds} {tail}",
                  f"python -m flows.ablation $D --tasks {','.join(TASKS)} --methods imitation --demo-steps "
                  + f"{PAPER_LN_DEMO_STEPS} --seeds {seeds} {tail}",
                  "python -m flows.ablation $D --tasks hammer --methods physics --demo-steps "
                  + f"{','.join(map(str, HAMMER_EXTRA_K))} --seeds {seeds} {tail}",
                  f"python -m flows.ablation --tasks <task> --methods joint --seeds {PLAN_SEEDS[0]} "
                  + f"--ln-timesteps <equal-frames steps> {tail}",
                  f"python -m flows.ablation $D --tasks <task> --methods joint_bc --demo-steps {PAPER_LN_DEMO_STEPS} "
                  + f"--seeds {PLAN_SEEDS[0]} --ln-timesteps <equal-frames steps> {tail}", "```"]
    if any(p.task in PLANNED_VARIANTS for p in missing):
        lines += ["", "Per variant (V: its own dataset, with at least 1,280 demos, and its PointNet, one variant at a "
                      + f"time, made as `{results_rel}/README.md` says; physics_gated only on "
                      + f"{', '.join(GATED_VARIANTS)}):",
                  "", "```",
                  "python -m flows.ablation $V --tasks <variant> --methods physics,bc,joint,imitation --demo-steps "
                  + f"0,{PAPER_LN_DEMO_STEPS} --seeds {seeds} {tail}",
                  "python -m flows.ablation $V --tasks <variant> --methods physics_gated --demo-steps "
                  + f"{PAPER_LN_DEMO_STEPS} --seeds {seeds} {tail}",
                  f"python -m flows.ablation $V --tasks <variant> --methods joint_bc --demo-steps {PAPER_LN_DEMO_STEPS} "
                  + f"--seeds {seeds} --ln-timesteps <equal-frames steps> {tail}", "```"]
    if budgets:
        lines += ["", "Equal-frames joint-control steps: " + "; ".join(budgets) + "."]
    return lines


def draw_figures(groups: Mapping[Group, Sequence[Mapping[str, Any]]], out_dir: Path) -> dict[str, list[Path]]:
    """Fig 8 per task against timesteps and against frames (``fig8_<task>_timesteps.png``, ``..._frames.png``): top
    physics K = 1,280 and K = 0 against joint control, bottom every demonstration-step count and BC; mean over
    seeds with a min-max band. Returns each task's files."""
    from prl.plots import plot_fig8_panels  # heavy: matplotlib

    out: dict[str, list[Path]] = {}
    for task in dict.fromkeys(g.task for g in groups):
        mine = {g: [s["rows"] for s in m] for g, m in groups.items() if g.task == task}
        top = {g.label: rows for g, rows in mine.items()
               if g.method in JOINT_A2C_METHODS or (g.method in ("physics", "physics_gated")
                                           and g.demo_steps in (0, PAPER_LN_DEMO_STEPS)
                                           and g.timesteps == PAPER_TIMESTEPS)}
        bottom = {g.label: rows for g, rows in mine.items() if g.method not in JOINT_METHODS}
        panels = [("physics-guided (K = 1,280 and K = 0) vs joint control and joint_bc", top),
                  ("demonstration steps K, and BC", bottom)]
        for x_key, x_label in (("timesteps", "timesteps (RL steps)"), ("frames", "simulated physics frames")):
            path = Path(out_dir) / f"fig8_{task}_{x_key}.png"
            plot_fig8_panels(panels, x_key, "window_success_rate", path, title=f"{task}: LN success while training",
                             x_label=x_label)
            out.setdefault(task, []).append(path)
    return out


def _rel(path: Path, start: Path) -> str:
    return Path(os.path.relpath(Path(path).resolve(), Path(start).resolve())).as_posix()


HOW_TO_READ = (
    f"- *pooled*: successes over all seeds' scenes with a 95% Wilson interval. *IQM*: the interquartile mean of the "
    f"seeds' success fractions with a 95% stratified-bootstrap interval (seeds resampled, then the scenes within "
    f"each seed; {BOOTSTRAP_REPS:,} draws, seed {BOOTSTRAP_SEED}): rliable's method (`prl/robust_stats.py`); with 3 "
    f"seeds no seed is trimmed and the IQM is the mean.\n"
    f"- *P(A > B)*: the probability that a seed of A scores above a seed of B (ties count half), averaged over tasks "
    f"(the last two columns over the paper's four tasks and over the task variants, apart), with its bootstrap "
    f"interval; 0.5 is no difference.\n"
    f"- *Across tasks*: the paper's four tasks and the task variants (`<task>_mixed`) are pooled apart.\n"
    f"- *training window success*: the success rate over the last update's worth of episodes, after the first and "
    f"after the last A2C update, per seed.")
"""The report's reading notes on its statistics."""
FIG8_TEXT = (
    "Success rate over the last update's worth of episodes while training; mean over seeds with a min-max band; log "
    f"axes (a joint-control step is {JOINT_FRAMES_PER_STEP} physics frames, a plan episode about 770). Top: "
    "physics-guided K = 1,280 and K = 0 against joint control and joint_bc; bottom: the demonstration steps and BC.")
"""What the report says of its figures."""
REWARD_TEXT = (
    "The LN's reward is the task's measure in the episode's outcome (the paper's d, N, theta, l), and success is the "
    "task's rule, which on some tasks asks more than the measure carries (the unscrew's cap gripped at the end, the "
    "tweeze's cube touched by no hand link, the hammer and the tweezers still on the table; `docs/guide/tasks.md`). Where "
    "a failure is paid at least as much as a success, RL can climb the reward away from success. Counted over the "
    "final evaluations of every point below; the reward is in the task's unit ({units}; a variant as its base "
    "task). A `physics_gated` point was paid it only where it succeeded; its failures are counted here with the "
    "measure they reached.")
"""What the report says of its reward table."""
PROVENANCE_TEXT = (
    "Each summary records the code version of what decides its outcome, for its task and method "
    "(`prl.version.outcome_version`: the joint-control environment enters only the joint-space methods', the plan "
    "environment and the export's readers only the plan-space methods'), each file's digest, the "
    "digest of its demonstrations, its settings and its MLflow run id (the store need not exist); a sweep re-runs a "
    "point whose summary differs from today's in any of them (`flows/ln_results.py`).")
"""What the report says of the summaries' provenance."""
REFERENCE_TEXT = (
    "- *(reference)* rows: plans that are not trained, executed on the same evaluation scenes as the points (the "
    "same eval seeds): the task's expert plan, a plan sampled from its prior per scene and, where an RN was given, "
    "the RN's argmax plan (`python -m flows.ln_reference`, `{results_rel}/reference-<task>.json`). A note under the "
    "table flags a reference whose scenes or code version are not the points'.")
"""What the report says of the reference rows (only when there are some)."""


def render(summaries: Mapping[str, Mapping[str, Any]], results_rel: str, results_link: str,
           figure_links: Mapping[str, Sequence[str]],
           references: Mapping[str, Mapping[str, Any]] | None = None, stale: Mapping[str, str] | None = None) -> str:
    """The report's markdown (see the module docstring): ``results_rel`` names the summaries' directory in the text
    and commands (relative to the repository), ``results_link`` and ``figure_links`` (each task's figures) are
    relative to the report; ``summaries`` and ``references`` (the reference plans' summaries by task) are the current
    ones; ``stale`` names the summaries left apart (``stale_points``), listed in their own section only."""
    stale = dict(stale or {})
    groups = grouped(summaries)
    eval_n = " or ".join(map(str, sorted({s["eval"]["n"] for s in summaries.values()})))
    intro = (f"Generated by `{COMMAND}` from the committed point summaries in [`{results_rel}/`]({results_link}/) "
             f"alone (no MLflow store, no `outputs/`); do not edit by hand: a sweep run with `--results-dir "
             f"{results_rel}` adds or replaces summaries, and the command makes this page and its figures again. "
             f"The pipeline's earlier runs, with their commands and dates, are in [the archive](archive/runs.md).")
    points = (f"- A point is one seed of one method: A2C over the Representation Space pre-trained on K "
              f"demonstration steps, actor and critic (`physics`; K = 0 is pure RL) or the actor alone (`bc`), or A2C "
              f"on the 30 joint targets (`joint control`), trained for {PAPER_TIMESTEPS:,} RL timesteps unless the row "
              f"says otherwise; its final deterministic plan is executed on {eval_n} unseen scenes (the RN "
              f"evaluation's).")
    lines = [f"<!-- Generated by `{COMMAND}` from {results_rel}/*.json; do not edit by hand. -->",
             "# Results: the Learning Network on the four tasks (Fig 8)", "", intro, "",
             "## How to read it", "", points, HOW_TO_READ]
    if references:
        lines.append(REFERENCE_TEXT.format(results_rel=results_rel))
    lines += ["", "## Stale summaries", "", *stale_section(stale)]
    lines += ["", "## Final success on unseen scenes", ""]
    lines += success_tables(groups, references)
    lines += ["## Across tasks", "", *across_tasks_table(groups), ""]
    lines += ["## Probability of improvement", "", *improvement_table(groups), ""]
    lines += ["## Reward against success", "", REWARD_TEXT.format(units=units_text(declared())), "",
              *reward_table(groups), ""]
    lines += ["## Fig 8", "", FIG8_TEXT, ""]
    for task, links in figure_links.items():
        alts = [f"{task}: Fig 8 against {Path(link).stem.rsplit('_', 1)[-1]}" for link in links]
        lines += [f"### {task}", "", *(f"![{alt}]({link})" for alt, link in zip(alts, links, strict=True)), ""]
    lines += ["## Compute", "", *compute_table(summaries), ""]
    lines += ["## Provenance", "", PROVENANCE_TEXT, "", *provenance_table(summaries), ""]
    lines += ["## Missing points", "", *missing_section(summaries, groups, results_rel)]
    return "\n".join(lines).rstrip("\n") + "\n"


def write_report(results_dir: Path, markdown: Path, figures_dir: Path, repo_root: Path | None = None,
                 find_stale: Callable[[Mapping[str, Mapping[str, Any]]], dict[str, str]] = stale_points) -> list[Path]:
    """Read every summary of ``results_dir`` (``prl.ln_summary.read_summaries``: errors name a missing directory or
    a malformed file) and its references (``prl.ln_reference.read_references``), draw the figures into ``figures_dir`` and write the report to ``markdown``; returns the
    files written. The report names the summaries' directory relative to ``repo_root`` (default: the checkout's)
    and links its files relative to itself. ``find_stale`` (``stale_points`` against today's code) names the
    summaries left apart."""
    summaries = read_summaries(results_dir)
    references = read_references(results_dir)
    stale = find_stale({**summaries, **{reference_file_name(t).removesuffix(".json"): r
                                          for t, r in references.items()}})
    summaries = {k: v for k, v in summaries.items() if k not in stale}
    references = {t: r for t, r in references.items() if reference_file_name(t).removesuffix(".json") not in stale}
    groups = grouped(summaries)
    figures = draw_figures(groups, figures_dir)
    here = Path(markdown).parent
    links = {task: [_rel(p, here) for p in paths] for task, paths in figures.items()}
    text = render(summaries, _rel(results_dir, repo_root or REPO_ROOT), _rel(results_dir, here), links, references,
                  stale)
    write_atomic(Path(markdown), text)
    return [Path(markdown), *[p for paths in figures.values() for p in paths]]
