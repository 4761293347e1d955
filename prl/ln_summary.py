"""The committed summary of one finished LN point (``docs/results/ln/<point>-t<timesteps>.json``): its schema, its
one byte form, its reading with errors that name the file, and the decision whether a sweep may reuse it.

A summary is one JSON object (sorted keys, indent 1, the curve's and outcomes' floats rounded to ``DIGITS``
decimals, no absolute local path), so that a diff of a re-run is readable and the same summary is the same bytes
on any machine:

- ``name``: the point's name (``ln-<task>-<method>-k<K>-seed<N>``) and ``point``: ``task``, ``method``
  (``prl.config.LN_METHODS``), ``demo_steps`` (K), ``seed``;
- ``timesteps``: the RL timesteps trained (the file name carries them: a point is also run at other budgets; 0
  for imitation, which trains no RL);
- ``settings``: everything else that decides the outcome (the LN's and SB3's parameters, the evaluation's scene
  seed and count, the plan environment's frames and points, the PointNet's keyed file name and the dataset's
  recipe, the flows' point procedure);
- ``code_version`` (``prl.version.outcome_version`` of the task and the point's method), ``code_files`` (the digest
  of each file it covers, ``prl.version.outcome_file_digests``; summaries made before it lack it) and, recorded,
  ``dataset_digest``
  (``demonstrations_digest`` of the task's demonstrations; null for joint control, which trains on none) and
  ``pointnet_sha256`` (the PointNet file's bytes);
- ``eval``: ``successes``, ``n``, ``ci95`` (Wilson) and ``outcomes``, one per evaluation scene (``seed``, ``plan``,
  ``success``, ``measure``, ``error``);
- ``rows``: the training curve, one row per A2C update (``timesteps``, ``frames``, ``window_success_rate``, ...),
  thinned evenly to at most ``MAX_ROWS`` (``thin_rows``: a joint-control run at the plan runs' frames has
  thousands of updates); empty for imitation, whose training curve is ``loss`` (``step``, ``loss``, ACT's terms,
  thinned alike);
- ``run_id`` (the MLflow run; its store need not exist), and the compute: ``train_seconds``, ``eval_seconds``,
  ``started`` and ``finished`` (ISO 8601, UTC), ``cores`` (the processes the point kept busy: 1 with one plan
  environment, else one per environment plus the main process).

A sweep reuses a summary (``reuse_decision``) only when its point, timesteps, settings and code version all equal
the ones the sweep would run now; anything else is re-run and the summary replaced. The dataset and the PointNet
enter by their recipes (the synthesis run's key and episode count; the PointNet's file name, a key of its config
and code version), not by their bytes: PhysX on the CPU repeats itself on one machine but not across machines, so
a new machine regenerating the same recipe gets demonstrations that differ in a few attempts' outcomes, and a
sweep that demanded equal bytes could never resume on another machine. The bytes' digests are recorded in each
summary, and the report counts the points per dataset digest, so a reader sees which points share demonstrations.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from prl.atomic import write_atomic
from prl.stats import wilson_interval
from prl.version import changed_files, outcome_file_digests, version_of

DIGITS = 4
"""Decimals kept of every float in a summary (the curves' rates and losses; measures)."""

RECORD_KEYS: tuple[str, ...] = ("point", "timesteps", "settings", "code_version")
"""What decides a point's outcome: a summary is reused only when all of these equal the sweep's (module docstring:
the dataset digest is recorded, not compared)."""

REQUIRED: dict[str, type | tuple[type, ...]] = {
    "name": str, "point": dict, "timesteps": int, "settings": dict, "code_version": str,
    "dataset_digest": (str, type(None)), "run_id": str, "eval": dict, "rows": list, "train_seconds": (int, float),
    "eval_seconds": (int, float), "started": str, "finished": str, "cores": int,
}
"""The keys every summary has, with their JSON types (what ``read_summary`` checks)."""

POINT_KEYS: dict[str, type] = {"task": str, "method": str, "demo_steps": int, "seed": int}
"""The keys of a summary's ``point``."""
EVAL_KEYS: dict[str, type | tuple[type, ...]] = {"successes": int, "n": int, "ci95": list, "outcomes": list}
"""The keys of a summary's ``eval``."""
OUTCOME_KEYS: dict[str, type | tuple[type, ...]] = {"seed": int, "success": bool}
"""The keys each of ``eval.outcomes`` has at least."""
MAX_ROWS = 400
"""Training-curve rows a summary keeps at most (``thin_rows``); the paper's 3,200 timesteps make 50."""
ROW_KEYS: tuple[str, ...] = ("timesteps", "frames", "window_success_rate")
"""The keys each training-curve row has at least (what the report draws)."""
LOSS_KEYS: tuple[str, ...] = ("step", "loss")
"""The keys each row of an imitation point's ``loss`` (its training curve; it has no RL update) has at least."""
REFERENCE_PREFIX = "reference-"
"""File names of the reference plans' summaries in the same directory (``prl.ln_reference``: the expert, the prior
and the RN on the points' evaluation scenes), which are not point summaries."""


class SummaryError(ValueError):
    """A summary file is missing, unreadable or malformed; the message names the file."""


def point_name(point: Mapping[str, Any]) -> str:
    """``ln-<task>-<method>-k<K>-seed<N>`` (``flows.train_ln.LNPoint.name``) of a summary's ``point``."""
    return f"ln-{point['task']}-{point['method']}-k{point['demo_steps']}-seed{point['seed']}"


def summary_file_name(name: str, timesteps: int) -> str:
    """The file of point ``name`` trained for ``timesteps``: ``<name>-t<timesteps>.json``."""
    return f"{name}-t{int(timesteps)}.json"


def compact(value: Any, digits: int | None = DIGITS) -> Any:
    """``value`` as plain JSON, recursively: every float rounded to ``digits`` decimals (None: kept whole), NaN and
    infinities as None, tuples as lists, numpy scalars as numbers. The curves and outcomes of a summary are
    written rounded; its settings whole."""
    if isinstance(value, bool) or value is None or isinstance(value, int | str):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            return None
        return value if digits is None else round(value, digits)
    if isinstance(value, Mapping):
        return {str(k): compact(v, digits) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [compact(v, digits) for v in value]
    if hasattr(value, "item"):  # a numpy scalar
        return compact(value.item(), digits)
    raise TypeError(f"a summary holds JSON values only, got {type(value).__name__}: {value!r}")


def thin_rows(rows: Sequence[Any], max_rows: int = MAX_ROWS) -> list[Any]:
    """``rows`` when there are at most ``max_rows``, else ``max_rows`` of them evenly spaced by index, the first and
    the last among them (row ``round(i (n - 1) / (max_rows - 1))`` for i = 0 .. max_rows - 1)."""
    if not isinstance(max_rows, int) or max_rows < 2:
        raise ValueError(f"max_rows must be an integer >= 2, got {max_rows!r}")
    n = len(rows)
    if n <= max_rows:
        return list(rows)
    return [rows[round(i * (n - 1) / (max_rows - 1))] for i in range(max_rows)]


def summary_bytes(summary: Mapping[str, Any]) -> bytes:
    """The one byte form of a summary: plain JSON (``compact`` without rounding), sorted keys, indent 1, a final
    newline."""
    return (json.dumps(compact(summary, None), sort_keys=True, indent=1, allow_nan=False) + "\n").encode()


def write_summary(directory: Path, summary: Mapping[str, Any]) -> Path:
    """Check ``summary`` (``check_summary``) and write it atomically to ``directory/summary_file_name(...)``; returns
    the path. A local absolute path in a string value is refused (a committed file must not carry one)."""
    data = json.loads(summary_bytes(summary))
    path = Path(directory) / summary_file_name(str(data.get("name")), int(data.get("timesteps", 0)))
    check_summary(data, path)
    return write_committed(path, data, "summary")


def write_committed(path: Path, data: Mapping[str, Any], what: str) -> Path:
    """Write checked ``data`` atomically to ``path`` in the one byte form; SummaryError when a string value is a
    local absolute path (a committed ``what`` must not carry one)."""
    absolute = [s for s in _strings(data) if s.startswith("/")]
    if absolute:
        raise SummaryError(f"{str(path)!r}: a committed {what} must not hold a local absolute path, got "
                           f"{absolute[0]!r}")
    return write_atomic(path, summary_bytes(data))


def _strings(value: Any) -> list[str]:
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [s for v in value.values() for s in _strings(v)]
    if isinstance(value, list):
        return [s for v in value for s in _strings(v)]
    return []


def _require(obj: Any, keys: Mapping[str, Any], where: str, path: Path) -> None:
    if not isinstance(obj, dict):
        raise SummaryError(f"{str(path)!r}: {where or 'the summary'} is not a JSON object")
    for key, kind in keys.items():
        if key not in obj:
            raise SummaryError(f"{str(path)!r}: missing key {where + key!r}")
        ok = isinstance(obj[key], kind) and (kind is bool or bool in _tuple(kind) or not isinstance(obj[key], bool))
        if not ok:
            raise SummaryError(f"{str(path)!r}: {where + key!r} must be {_kind_name(kind)}, got {obj[key]!r}")


def _tuple(kind: Any) -> tuple:
    return kind if isinstance(kind, tuple) else (kind,)


def _kind_name(kind: Any) -> str:
    names = {str: "a string", int: "an integer", float: "a number", bool: "true or false", dict: "an object",
             list: "a list", type(None): "null"}
    return " or ".join(names.get(k, k.__name__) for k in _tuple(kind))


def check_summary(summary: Any, path: Path) -> None:
    """SummaryError naming ``path`` and the first missing or mistyped key of ``summary`` (see the module
    docstring), a name that is not its point's, or a file name that is not its name and timesteps."""
    path = Path(path)
    _require(summary, REQUIRED, "", path)
    _require(summary["point"], POINT_KEYS, "point.", path)
    _require(summary["eval"], EVAL_KEYS, "eval.", path)
    for i, outcome in enumerate(summary["eval"]["outcomes"]):
        _require(outcome, OUTCOME_KEYS, f"eval.outcomes[{i}].", path)
    for i, row in enumerate(summary["rows"]):
        _require(row, dict.fromkeys(ROW_KEYS, (int, float)), f"rows[{i}].", path)
    _require(summary, {"loss": list} if "loss" in summary else {}, "", path)
    for i, row in enumerate(summary.get("loss", [])):
        _require(row, dict.fromkeys(LOSS_KEYS, (int, float)), f"loss[{i}].", path)
    ev = summary["eval"]
    if ev["n"] != len(ev["outcomes"]) or ev["successes"] != sum(o["success"] for o in ev["outcomes"]):
        raise SummaryError(f"{str(path)!r}: eval says {ev['successes']}/{ev['n']} but its outcomes hold "
                           f"{sum(o['success'] for o in ev['outcomes'])}/{len(ev['outcomes'])}")
    if summary["name"] != point_name(summary["point"]):
        raise SummaryError(f"{str(path)!r}: name {summary['name']!r} is not its point's "
                           f"{point_name(summary['point'])!r}")
    expected = summary_file_name(summary["name"], summary["timesteps"])
    if path.name != expected:
        raise SummaryError(f"{str(path)!r}: a summary of {summary['name']!r} at {summary['timesteps']} timesteps "
                           f"belongs in a file named {expected!r}")


def read_summary(path: Path) -> dict[str, Any]:
    """The summary at ``path``, checked (``check_summary``); SummaryError naming the file when it is not valid
    JSON or malformed. A ``point`` of an older summary names its method ``variant``; it is read as ``method``."""
    path = Path(path)
    summary = read_json(path, "summary")
    point = summary.get("point") if isinstance(summary, dict) else None
    if isinstance(point, dict) and "variant" in point and "method" not in point:
        point["method"] = point.pop("variant")  # the LN method's former name (summaries written before 2026-12-06)
    check_summary(summary, path)
    return summary


def read_json(path: Path, what: str) -> Any:
    """The JSON value in ``path``; SummaryError naming the file (a ``what`` file) when it is missing or not JSON."""
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise SummaryError(f"{str(path)!r}: no such {what} file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SummaryError(f"{str(path)!r}: not valid JSON ({exc})") from None


def read_summaries(directory: Path) -> dict[str, dict[str, Any]]:
    """Every point summary (``*.json`` but the reference plans' ``reference-*.json``) in ``directory``, by file stem
    in sorted order. FileNotFoundError naming a missing directory or one without any summary; SummaryError naming a
    malformed file."""
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"no LN summaries directory at {str(directory)!r}")
    paths = sorted(p for p in directory.glob("*.json") if not p.name.startswith(REFERENCE_PREFIX))
    if not paths:
        raise FileNotFoundError(f"no LN summary (*.json) in {str(directory)!r}")
    return {p.stem: read_summary(p) for p in paths}


def _normal(value: Any) -> Any:
    """``value`` as it reads back from a summary (compacted, through JSON: tuples become lists)."""
    return json.loads(json.dumps(compact(value, None), sort_keys=True))


def reuse_decision(existing: Mapping[str, Any] | None, expected: Mapping[str, Any],
                   keys: Sequence[str] = RECORD_KEYS) -> tuple[bool, str]:
    """Whether a sweep may take the summary ``existing`` (None: there is none) for the point it would run with
    ``expected`` (``keys``, by default ``RECORD_KEYS``: point, timesteps, settings, code_version; a reference
    summary's are ``prl.ln_reference.REFERENCE_RECORD_KEYS``), and why: reused only when all of them are equal;
    else the reason names what differs (each changed setting, old -> new)."""
    missing = [k for k in keys if k not in expected]
    if missing:
        raise ValueError(f"expected record lacks {missing}; it needs {list(keys)}")
    if existing is None:
        return False, "no summary yet"
    old, new = _normal({k: existing.get(k) for k in keys}), _normal({k: expected[k] for k in keys})
    reasons = []
    for key in keys:
        if old[key] == new[key]:
            continue
        if key == "settings" and isinstance(old[key], dict):
            changed = sorted(set(old[key]) | set(new[key]))
            diffs = [f"{k} {old[key].get(k, '(absent)')!r} -> {new[key].get(k, '(absent)')!r}" for k in changed
                     if old[key].get(k, "(absent)") != new[key].get(k, "(absent)")]
            reasons.append("settings differ: " + "; ".join(diffs))
        else:
            reasons.append(f"{key} {old[key]!r} -> {new[key]!r}")
    if reasons:
        return False, "; ".join(reasons)
    names = [k.replace("_", " ") for k in keys]
    return True, "same " + (", ".join(names[:-1]) + " and " if len(names) > 1 else "") + names[-1]


def demonstrations_digest(task: str, seeds: Sequence[int], plans: Sequence[Sequence[int]],
                          rewards: Sequence[float], extra: Mapping[str, Any] | None = None) -> str:
    """A digest (16 hex digits) of a task's demonstrations as an LN point trains on them: per episode, in dataset
    order, its scene seed, commanded plan and reward, and any ``extra`` per-episode values (arrays whose first axis
    is the episode, e.g. a training weight) by name; each float (a float32 reward too) as its exact decimal.
    Deterministic synthesis regenerates the same episodes on any machine, so the digest is the same there; the
    demonstrations' x also depends on the PointNet, whose file digest is a setting of its own. ValueError naming a
    column of another length."""
    columns = {"plans": plans, "rewards": rewards, **{f"extra {k!r}": v for k, v in (extra or {}).items()}}
    for name, values in columns.items():
        if len(values) != len(seeds):
            raise ValueError(f"task {task!r}: {len(seeds)} seeds but {len(values)} {name}; each demonstration "
                             "needs one of each")
    episodes = [[int(s), [int(v) for v in p], float(r)] for s, p, r in zip(seeds, plans, rewards, strict=True)]
    payload: dict[str, Any] = {"task": task, "episodes": episodes}
    if extra:
        payload["extra"] = {k: np.asarray(extra[k], dtype=float).tolist() for k in sorted(extra)}
    return hashlib.sha256(json.dumps(payload, separators=(",", ":")).encode()).hexdigest()[:16]


def rate_cell(successes: int, n: int) -> str:
    """``'44/50 = 0.88 (0.76-0.94)'``: a report table's success count with its rate and Wilson interval (``'0/0'``
    for no trial)."""
    if n == 0:
        return "0/0"
    lo, hi = wilson_interval(successes, n)
    return f"{successes}/{n} = {successes / n:.2f} ({lo:.2f}-{hi:.2f})"


def stale_points(summaries: Mapping[str, Mapping[str, Any]],
                 current_files: Callable[[str, str], dict[str, str]] = outcome_file_digests) -> dict[str, str]:
    """``{name: why}`` of the summaries (points, or references by ``reference-<task>``) whose recorded ``code_version``
    is not the current one of their task and method (``current_files(task, method)``, by default
    ``prl.version.outcome_file_digests``): the files whose digests changed, named from the summary's
    ``code_files``."""
    out = {}
    for name, s in summaries.items():
        task = s["point"]["task"] if "point" in s else s["task"]
        method = s["point"]["method"] if "point" in s else "reference"
        try:
            current = current_files(task, method)
        except FileNotFoundError:
            out[name] = f"the task {task!r} has no module any more"
            continue
        if s["code_version"] == version_of(current):
            continue
        changed = changed_files(s.get("code_files"), current)
        out[name] = ("code version differs (the summary records no per-file digests)" if changed is None
                     else "changed: " + ", ".join(f"`{f}`" for f in changed))
    return out


def stale_section(stale: Mapping[str, str]) -> list[str]:
    """The stale summaries, one row each with the files that changed since they were made."""
    if not stale:
        return [("No committed summary is stale: every point and reference on this page ran on today's code of its "
                 "task and method.")]
    lines = [(f"{len(stale)} committed summaries ran on code that has changed since (`prl.version.outcome_version` of "
             "their task and method): they are left out of every table and figure of this page and count as missing "
             "below until they are run again."), "", "| summary | why |", "|---|---|"]
    lines += [f"| {name} | {why} |" for name, why in sorted(stale.items())]
    return lines
