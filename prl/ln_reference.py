"""The committed reference plans of one task (``docs/results/ln/reference-<task>.json``): the task's expert plan, a
plan sampled from its prior per scene and, when an RN was given, the RN's argmax plan, each executed on the LN
points' evaluation scenes, so that the report shows every point's final plan next to them on the same scenes.
Written by ``python -m flows.ln_reference``; its schema, its rows and note in the report (``reference_rows``,
``reference_note``), its one byte form (``prl.ln_summary.summary_bytes``: sorted
keys, indent 1, no local absolute path), its reading with errors that name the file, and its reuse rule.

A reference summary is one JSON object:

- ``task``: the task (the file is ``reference-<task>.json``);
- ``settings``: what decides its outcome beside the code: ``eval_seed`` and ``eval_scenes`` (the scenes are
  ``envs.trials.eval_scene_seeds(eval_seed, eval_scenes)``, the points'), ``n_frames``, ``prior_seed`` (the prior
  plans' seed), ``procedure`` (``flows.ln_reference.REFERENCE_PROCEDURE``) and, with an RN, ``rn`` (its file name),
  ``rn_sha256`` (its bytes: an RN's file name is not keyed), ``pointnet`` (the PointNet's keyed file name) and
  ``n_points`` and, on a mixed variant with a search record (``envs.variant_search``), ``best_fixed``: the best
  fixed plan that search found;
- ``code_version``: ``prl.version.outcome_version`` of the task for a plan-space method, as the plan points', and
  ``code_files``, the digest of each of its files (``prl.version.outcome_file_digests``);
- ``plans``: per plan kind (``REFERENCE_KINDS``: ``expert``, ``prior``, with an RN ``rn`` and, on a mixed variant,
  ``oracle``, ``best_fixed`` and ``family <k> expert``) ``successes``,
  ``n``, ``ci95`` (Wilson) and ``outcomes``, one per scene (``seed``, ``plan``, ``success``, ``measure``,
  ``error``), every kind on the same scenes in the same order;
- ``started`` and ``finished`` (ISO 8601, UTC).

A reference is reused (``reference_reuse``) when its task, settings and code version all equal the ones the command
would run now (``REFERENCE_RECORD_KEYS``); anything else is computed again and the file replaced.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from prl.ln_summary import (
    REFERENCE_PREFIX,
    SummaryError,
    _require,
    compact,
    rate_cell,
    read_json,
    reuse_decision,
    summary_bytes,
    write_committed,
)
from prl.stats import wilson_interval

REFERENCE_KINDS: tuple[str, ...] = ("expert", "prior", "rn", "oracle", "best_fixed")
"""The reference plan kinds, in the report's order: the expert plan, a prior-sampled plan, the RN's argmax plan and,
on a mixed variant (``envs.families``), the family oracle and the best fixed plan its search found
(``envs.variant_search``); then each family's expert (``family <k> expert``)."""
SETTING_KINDS: tuple[str, ...] = ("rn", "best_fixed")
"""The plan kinds that go with a setting of the same name (the RN's file name, the best fixed plan): a reference has
the kind exactly when it has the setting."""
FAMILY_KIND = re.compile(r"family (\d+) expert")
"""A mixed variant's kind of one family's expert plan on every scene."""
REQUIRED_KINDS: tuple[str, ...] = ("expert", "prior")
"""The kinds every reference has (the RN's only when the command was given one; the oracle and the families' on a
mixed variant)."""
REFERENCE_LABELS: dict[str, str] = {"expert": "expert plan", "prior": "prior-sampled plan", "rn": "RN argmax plan",
                                    "oracle": "family oracle (each scene's own family's expert)",
                                    "best_fixed": "best fixed plan of the variant search"}
"""How the report names each kind (``family <k> expert``: "family k's expert plan")."""


def reference_kinds(kinds: Iterable[str]) -> list[str]:
    """The reference kinds among ``kinds``, in the report's order: ``REFERENCE_KINDS``, then the families' experts by
    family index."""
    kinds = set(kinds)
    family = sorted((k for k in kinds if FAMILY_KIND.fullmatch(k)), key=lambda k: int(FAMILY_KIND.fullmatch(k)[1]))
    return [k for k in REFERENCE_KINDS if k in kinds] + family


def reference_label(kind: str) -> str:
    """How the report names a reference kind."""
    match = FAMILY_KIND.fullmatch(kind)
    return f"family {match[1]}'s expert plan" if match else REFERENCE_LABELS[kind]
REFERENCE_RECORD_KEYS: tuple[str, ...] = ("task", "settings", "code_version")
"""What decides a reference's outcome: it is reused only when all of these equal the command's."""

REQUIRED: dict[str, type | tuple[type, ...]] = {"task": str, "settings": dict, "code_version": str, "plans": dict,
                                               "started": str, "finished": str}
"""The keys every reference summary has, with their JSON types."""
SETTINGS_KEYS: dict[str, type | tuple[type, ...]] = {"eval_seed": int, "eval_scenes": int, "n_frames": int}
"""The keys of a reference's ``settings`` that the report relies on (``rn`` too when it has the RN's plans)."""
PLAN_KEYS: dict[str, type | tuple[type, ...]] = {"successes": int, "n": int, "ci95": list, "outcomes": list}
"""The keys of each plan kind's result."""
OUTCOME_KEYS: dict[str, type | tuple[type, ...]] = {"seed": int, "plan": list, "success": bool,
                                                    "measure": (int, float, type(None))}
"""The keys each scene's outcome has at least."""


def reference_file_name(task: str) -> str:
    """The reference file of ``task``: ``reference-<task>.json``."""
    return f"{REFERENCE_PREFIX}{task}.json"


def plan_result(outcomes: Iterable[Any]) -> dict[str, Any]:
    """One plan kind's result from its trial outcomes (``envs.trials.TrialOutcome`` or anything with ``seed``,
    ``plan``, ``success``, ``measure``, ``error``), in order: successes, n, the Wilson ``ci95`` and the rounded
    per-scene outcomes. ValueError for no outcome."""
    rows = [{"seed": int(o.seed), "plan": [int(v) for v in o.plan], "success": bool(o.success),
             "measure": float(o.measure), "error": str(o.error)} for o in outcomes]
    if not rows:
        raise ValueError("a plan kind's result needs at least one outcome, got none")
    k = sum(r["success"] for r in rows)
    return {"successes": k, "n": len(rows), "ci95": compact(list(wilson_interval(k, len(rows)))),
            "outcomes": compact(rows)}


def check_reference(ref: Any, path: Path) -> None:
    """SummaryError naming ``path`` and what is wrong: a missing or mistyped key (module docstring), a plan kind
    that is unknown or missing, counts that are not the outcomes', kinds on other scenes than the expert's or
    other than ``eval_scenes`` of them, RN or best fixed plans without their setting (``SETTING_KINDS``) or the
    setting without the plans, best fixed outcomes of another plan than the setting's, or a file name that is not
    ``reference-<task>.json``."""
    path = Path(path)
    _require(ref, REQUIRED, "", path)
    _require(ref["settings"], SETTINGS_KEYS, "settings.", path)
    plans = ref["plans"]
    unknown = sorted(set(plans) - set(reference_kinds(plans)))
    missing = [k for k in REQUIRED_KINDS if k not in plans]
    if unknown or missing:
        raise SummaryError(f"{str(path)!r}: plans must be {', '.join(REQUIRED_KINDS)} and optionally rn, oracle, "
                           f"best_fixed and 'family <k> expert'; "
                           + (f"unknown {unknown}" if unknown else f"missing {missing}"))
    for kind in SETTING_KINDS:
        if (kind in plans) != (kind in ref["settings"]):
            raise SummaryError(f"{str(path)!r}: plans.{kind} and settings.{kind} go together; "
                               + (f"the plans have no {kind}" if kind in ref["settings"] else f"settings.{kind} is missing"))
    scenes = None
    for kind in reference_kinds(plans):
        result = plans[kind]
        _require(result, PLAN_KEYS, f"plans.{kind}.", path)
        for i, outcome in enumerate(result["outcomes"]):
            _require(outcome, OUTCOME_KEYS, f"plans.{kind}.outcomes[{i}].", path)
        outcomes = result["outcomes"]
        k = sum(o["success"] for o in outcomes)
        if result["n"] != len(outcomes) or result["successes"] != k:
            raise SummaryError(f"{str(path)!r}: plans.{kind} says {result['successes']}/{result['n']} but its "
                               f"outcomes hold {k}/{len(outcomes)}")
        if len(outcomes) != ref["settings"]["eval_scenes"]:
            raise SummaryError(f"{str(path)!r}: plans.{kind} has {len(outcomes)} outcomes, settings.eval_scenes "
                               f"is {ref['settings']['eval_scenes']}")
        seeds = [o["seed"] for o in outcomes]
        if scenes is not None and seeds != scenes:
            raise SummaryError(f"{str(path)!r}: plans.{kind} ran on other scenes than plans.expert "
                               f"({seeds} != {scenes})")
        scenes = seeds
    if "best_fixed" in plans:
        plan = list(ref["settings"]["best_fixed"])
        other = [o["plan"] for o in plans["best_fixed"]["outcomes"] if list(o["plan"]) != plan]
        if other:
            raise SummaryError(f"{str(path)!r}: plans.best_fixed ran {other[0]}, settings.best_fixed is {plan}")
    expected = reference_file_name(ref["task"])
    if path.name != expected:
        raise SummaryError(f"{str(path)!r}: the reference of task {ref['task']!r} belongs in a file named "
                           f"{expected!r}")


def reference_seeds(ref: Mapping[str, Any]) -> list[int]:
    """The scene seeds a (checked) reference ran on, in order."""
    return [int(o["seed"]) for o in ref["plans"]["expert"]["outcomes"]]


def read_reference(path: Path) -> dict[str, Any]:
    """The reference summary at ``path``, checked (``check_reference``); SummaryError naming the file when it is
    missing, not valid JSON or malformed."""
    path = Path(path)
    ref = read_json(path, "reference")
    check_reference(ref, path)
    return ref


def read_references(directory: Path) -> dict[str, dict[str, Any]]:
    """Every reference summary (``reference-*.json``) in ``directory``, by task in file-name order; empty when
    there is none (or no directory). SummaryError naming a malformed file."""
    directory = Path(directory)
    paths = sorted(directory.glob(f"{REFERENCE_PREFIX}*.json")) if directory.is_dir() else []
    refs = [read_reference(p) for p in paths]
    return {r["task"]: r for r in refs}


def write_reference(directory: Path, ref: Mapping[str, Any]) -> Path:
    """Check ``ref`` (``check_reference``) and write it atomically to ``directory/reference-<task>.json`` in the
    one byte form of the point summaries; returns the path. A local absolute path in a string value is refused."""
    data = json.loads(summary_bytes(ref))
    path = Path(directory) / reference_file_name(str(data.get("task")))
    check_reference(data, path)
    return write_committed(path, data, "reference")


def reference_reuse(existing: Mapping[str, Any] | None, expected: Mapping[str, Any]) -> tuple[bool, str]:
    """Whether the command may keep the reference ``existing`` (None: there is none) for the one it would compute
    with ``expected`` (``REFERENCE_RECORD_KEYS``), and why (``prl.ln_summary.reuse_decision``)."""
    return reuse_decision(existing, expected, REFERENCE_RECORD_KEYS)


def reference_rows(ref: Mapping[str, Any]) -> list[str]:
    """A report success-table row per plan kind of a reference: not trained, one run."""
    rows = []
    for kind in reference_kinds(ref["plans"]):
        r = ref["plans"][kind]
        rows.append(f"| {reference_label(kind)} (reference) | - | {r['successes']}/{r['n']} "
                    f"| {rate_cell(r['successes'], r['n'])} | - | not trained |")
    return rows


def best_fixed_text(settings: Mapping[str, Any]) -> str:
    """The reference sentence's words for the best fixed plan of a variant's search (none without one)."""
    plan = settings.get("best_fixed")
    return f", the best fixed plan its search found (`{plan}`, [variant search](variant_search.md))" if plan else ""


def reference_note(ref: Mapping[str, Any], members: Sequence[Mapping[str, Any]]) -> str:
    """Where a task's reference rows come from, and whether they ran on its points' scenes and code version (a
    flag when not)."""
    st, seeds = ref["settings"], reference_seeds(ref)
    rn = f"; the RN is `{st['rn']}`" if "rn" in ref["plans"] else ""
    text = (f"Reference rows (`{reference_file_name(ref['task'])}`): the task's expert plan, a plan sampled from its "
            f"prior per scene{' and the RN argmax plan' if 'rn' in ref['plans'] else ''}"
            f"{', the family oracle and each family expert plan' if 'oracle' in ref['plans'] else ''}"
            f"{best_fixed_text(st)}, executed on the "
            f"{len(seeds)} scenes of eval seed {st['eval_seed']} (scene seeds {seeds[0]} to {seeds[-1]}){rn}.")
    if not members:
        return text + " No point of this task yet."
    point_seeds = {tuple(o["seed"] for o in s["eval"]["outcomes"]) for s in members}
    if point_seeds == {tuple(seeds)}:
        text += " The same scenes as every point's above."
    else:
        evals = sorted({(s["settings"].get("eval_seed"), len(s["eval"]["outcomes"])) for s in members}, key=str)
        text += (" **Not the points' scenes**: the points ran on "
                 + ", ".join(f"{n} scenes of eval seed {seed}" for seed, n in evals) + ".")
    versions = sorted({s["code_version"] for s in members})
    if versions == [ref["code_version"]]:
        text += f" The same code version as the points (`{ref['code_version']}`)."
    else:
        text += (f" **Another code version**: the reference's `{ref['code_version']}`, the points' "
                 + ", ".join(f"`{v}`" for v in versions) + ".")
    return text
