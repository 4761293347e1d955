"""What a pipeline run shows on the Artifacts page of a Prefect server: a keyed table per stage that has one,
and a markdown summary of the run.

Keys are fixed per stage (and task), so every run adds a version of the same artifact and the page shows the
latest with its history: ``trial-rates-<task>`` (success rate per plan kind), ``synthesis-yield`` (demos kept
per task), ``label-agreement`` (recovered labels against the commanded plans, per dimension),
``rn-success`` and ``ln-success`` (success per task, split and plan kind, with 95% intervals) and
``pipeline-summary``. Prefect allows lowercase letters, numbers and dashes in a key (:func:`artifact_key`).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

from prefect.artifacts import create_markdown_artifact, create_table_artifact

from prl.stats import wilson_interval

_KEY = re.compile(r"[a-z0-9-]+")

SUMMARY_KEY = "pipeline-summary"
"""Key of the run's markdown summary."""


def artifact_key(*parts: str) -> str:
    """``parts`` joined by dashes, underscores as dashes (``("trial-rates", "hammer")`` -> ``trial-rates-hammer``);
    ValueError naming a key Prefect would refuse (anything but lowercase letters, numbers and dashes)."""
    key = "-".join(parts).replace("_", "-")
    if not _KEY.fullmatch(key):
        raise ValueError(f"artifact key {key!r} must hold only lowercase letters, numbers and dashes")
    return key


def rate_row(successes: int, n: int, **columns: Any) -> dict[str, Any]:
    """A table row: ``columns``, then the success count, rate and its 95% Wilson interval."""
    lo, hi = wilson_interval(successes, n) if n else (0.0, 1.0)
    return {**columns, "successes": f"{successes}/{n}", "rate": round(successes / n, 3) if n else None,
            "95% CI": f"{lo:.2f}-{hi:.2f}"}


def publish_table(key: str, rows: Sequence[Mapping[str, Any]], description: str) -> None:
    """Publish ``rows`` (one dict per row, same columns) as the table artifact ``key`` of the current run."""
    create_table_artifact(table=[dict(r) for r in rows], key=artifact_key(key), description=description)


def publish_summary(markdown: str, description: str = "What this pipeline run did and found") -> None:
    """Publish ``markdown`` as the run's summary artifact (``SUMMARY_KEY``)."""
    create_markdown_artifact(markdown=markdown, key=SUMMARY_KEY, description=description)


def markdown_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """``rows`` (same columns) as a markdown table."""
    if not rows:
        return "(none)"
    cols = list(rows[0])
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(str(r.get(c, "")) for c in cols) + " |" for r in rows]
    return "\n".join(lines)
