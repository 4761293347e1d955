"""Figures logged to MLflow and shown in docs/ (matplotlib, headless).

Each function saves its figure as a PNG at ``out`` and returns the ``matplotlib.figure.Figure`` (built without
pyplot, so nothing stays open in a global registry), which the flows log with ``mlflow.log_figure``."""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np


def plot_trial_rates(task: str, rates: Mapping[str, float], counts: Mapping[str, int],
                     measures: Mapping[str, Sequence[float]], measure_name: str, out: Path) -> Any:
    """Bar chart of success rate per plan kind, and the distribution of the measured quantity."""
    from matplotlib.figure import Figure  # heavy: matplotlib

    kinds = list(rates)
    fig = Figure(figsize=(9, 3.4))
    ax0, ax1 = fig.subplots(1, 2)
    bars = ax0.bar(kinds, [rates[k] for k in kinds], color=["tab:green", "tab:orange", "tab:gray"][: len(kinds)])
    for bar, k in zip(bars, kinds):
        ax0.text(bar.get_x() + bar.get_width() / 2, bar.get_height() + 0.02, f"{rates[k]:.2f}\n(n={counts[k]})",
                 ha="center", va="bottom", fontsize=8)
    ax0.set_ylim(0, 1.25)
    ax0.set_ylabel("success rate (simulated)")
    ax0.set_title(f"{task}: plans executed on randomised scenes")
    present = [np.asarray(v, dtype=float) for v in measures.values() if len(v)]
    top = max([float(v.max()) for v in present] + [1e-6])
    bottom = min([float(v.min()) for v in present] + [0.0])  # a measure can be negative (a cube fallen below its rest)
    bins = np.linspace(bottom, top, 26)  # shared bins, so the kinds compare bar for bar
    for k in kinds:
        values = np.asarray(measures[k], dtype=float)
        if values.size:
            ax1.hist(values, bins=bins, alpha=0.6, label=k)
    ax1.set_xlabel(measure_name)
    ax1.set_ylabel("episodes")
    ax1.legend()
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    return fig


def plot_rn_probabilities(probs_by_task: Mapping[str, Sequence[np.ndarray]], dim_names: Sequence[str],
                          choice_names: Sequence[Sequence[str]], out: Path, tau: float = 2.0,
                          weights_by_task: Mapping[str, Sequence[float]] | None = None) -> Any:
    """The paper's Fig 7 redrawn: one row per task, one bar chart per RS dimension.

    ``probs_by_task[task][i]`` is the (N, m_i) RN probabilities of dimension i over the task's samples;
    each bar is the mean predicted probability of a choice. Key dimensions (``prl.rn_decode.key_dimensions``:
    the top mean probability exceeds ``tau / m_i``, drawn as a dashed line) are drawn in colour with
    their top choice highlighted; the others in grey. ``weights_by_task[task]``: the samples' weights in the
    means (the demos' importance weights, ``prl.proposal``); missing: equal."""
    from matplotlib.figure import Figure  # heavy: matplotlib

    from prl.rn_decode import key_dimensions

    if not probs_by_task:
        raise ValueError("probs_by_task is empty; give at least one task")
    n = len(dim_names)
    if len(choice_names) != n:
        raise ValueError(f"{len(dim_names)} dimension names but {len(choice_names)} choice-name lists")
    for task, probs in probs_by_task.items():
        if len(probs) != n:
            raise ValueError(f"task {task!r} has probabilities for {len(probs)} dimensions, expected {n}")
        for i, p in enumerate(probs):
            width = np.shape(p)[-1] if np.ndim(p) == 2 else None
            if width != len(choice_names[i]):
                raise ValueError(f"task {task!r}, dimension {dim_names[i]!r}: probabilities of shape {np.shape(p)}, "
                                 f"expected (samples, {len(choice_names[i])})")
    tasks = list(probs_by_task)
    fig = Figure(figsize=(2.3 * n, 1.9 * len(tasks) + 0.6))
    axes = fig.subplots(len(tasks), n, squeeze=False)
    for r, task in enumerate(tasks):
        summaries = key_dimensions(probs_by_task[task], tau=tau, weights=(weights_by_task or {}).get(task))
        for c, s in enumerate(summaries):
            ax = axes[r][c]
            m = len(s.mean_probs)
            if s.key:
                colors = ["tab:red" if k == s.top_choice else "tab:blue" for k in range(m)]
            else:
                colors = ["tab:gray"] * m
            ax.bar(range(m), s.mean_probs, color=colors)
            ax.axhline(s.threshold, color="k", ls="--", lw=0.7)
            ax.set_ylim(0, 1.0)
            ax.set_xticks(range(m))
            ax.set_xticklabels([str(name) for name in choice_names[c]], rotation=60, ha="right", fontsize=6)
            ax.tick_params(axis="y", labelsize=7)
            title = f"a{c} {dim_names[c]}" + (" [key]" if s.key else "")
            ax.set_title(title, fontsize=7, fontweight="bold" if s.key else "normal")
            if s.key:
                for spine in ax.spines.values():
                    spine.set_edgecolor("tab:red")
                    spine.set_linewidth(1.5)
            if c == 0:
                ax.set_ylabel(f"{textwrap.fill(task, 26)}\nmean prob.", fontsize=8)  # long labels kept in the row
    fig.suptitle(f"RN predicted probabilities per choice (key: top mean prob. > {tau:g}/m, dashed)", fontsize=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    return fig


def plot_learning_curves(curves: Mapping[str, Sequence[Sequence[Mapping[str, float]]]], x_key: str, y_key: str,
                         out: Path, title: str = "", x_label: str | None = None, log_x: bool = False) -> Any:
    """The paper's Fig 8 redrawn: for each method, ``y_key`` against ``x_key`` as the mean over seeds with a
    band from the lowest to the highest seed. ``curves[method]`` is one list of rows per seed (the LN's
    per-update rows, first point at the end of the first update); seeds are aligned on their common ``x_key``
    range by linear interpolation. ``log_x`` puts ``x_key`` on a log scale (budgets that differ by 100x)."""
    from matplotlib.figure import Figure  # heavy: matplotlib

    if not curves:
        raise ValueError("curves is empty; give at least one method")
    fig = Figure(figsize=(6, 3.6))
    ax = fig.subplots()
    draw_learning_curves(ax, curves, x_key, y_key, x_label=x_label, log_x=log_x)
    ax.set_title(title)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    return fig


def draw_learning_curves(ax: Any, curves: Mapping[str, Sequence[Sequence[Mapping[str, float]]]], x_key: str,
                         y_key: str, x_label: str | None = None, log_x: bool = False,
                         colors: Mapping[str, str] | None = None) -> None:
    """``plot_learning_curves``' curves drawn on the matplotlib axes ``ax`` (``colors``: a colour per method, so
    that one method keeps its colour across panels)."""
    for method, runs in curves.items():
        runs = [r for r in runs if r]
        if not runs:
            continue
        start = max(r[0][x_key] for r in runs)
        end = min(r[-1][x_key] for r in runs)
        grid = np.linspace(start, max(end, start), 100)
        ys = np.stack([np.interp(grid, [row[x_key] for row in r], [row[y_key] for row in r]) for r in runs])
        few = len(runs[0]) < 3  # a curve of one or two updates: its ends marked, not every grid point
        line, = ax.plot(grid, ys.mean(axis=0), label=f"{method} ({len(runs)} seed{'s' if len(runs) > 1 else ''})",
                        marker="o" if few else None, markevery=[0, len(grid) - 1] if few else None,
                        color=(colors or {}).get(method))
        if len(runs) > 1:
            ax.fill_between(grid, ys.min(axis=0), ys.max(axis=0), color=line.get_color(), alpha=0.2)
    if log_x:
        ax.set_xscale("log")
    ax.set_xlabel(x_label or x_key)
    ax.set_ylabel(y_key.replace("_", " "))
    ax.set_ylim(-0.03, 1.03)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)


def plot_fig8_panels(panels: Sequence[tuple[str, Mapping[str, Sequence[Sequence[Mapping[str, float]]]]]],
                     x_key: str, y_key: str, out: Path, title: str = "", x_label: str | None = None,
                     log_x: bool = True) -> Any:
    """Fig 8 of one task as stacked panels (``panels``: a title and its ``plot_learning_curves`` curves each; an
    empty panel says so), each method in one colour throughout. Saved as a PNG without the matplotlib version
    in its metadata, so that the same curves give the same bytes."""
    from matplotlib.figure import Figure  # heavy: matplotlib

    if not panels:
        raise ValueError("panels is empty; give at least one")
    names = sorted({v for _, curves in panels for v in curves})
    palette = [f"C{i % 10}" for i in range(len(names))]
    colors = dict(zip(names, palette, strict=True))
    fig = Figure(figsize=(6.4, 3.3 * len(panels)))
    axes = fig.subplots(len(panels), 1, squeeze=False)[:, 0]
    for ax, (panel_title, curves) in zip(axes, panels, strict=True):
        if any(any(r) for r in curves.values()):
            draw_learning_curves(ax, curves, x_key, y_key, x_label=x_label, log_x=log_x, colors=colors)
        else:
            ax.text(0.5, 0.5, "no point yet", ha="center", va="center", transform=ax.transAxes)
            ax.set_xlabel(x_label or x_key)
        ax.set_title(panel_title, fontsize=9)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, metadata={"Software": None})
    return fig
