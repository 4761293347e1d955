"""Figures logged to MLflow and shown in the README (matplotlib, headless)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np


def plot_trial_rates(task: str, rates: Mapping[str, float], counts: Mapping[str, int],
                     measures: Mapping[str, Sequence[float]], measure_name: str, out: Path) -> Path:
    """Bar chart of success rate per plan kind, and the distribution of the measured quantity."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = list(rates)
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(9, 3.4))
    bars = ax0.bar(kinds, [rates[k] for k in kinds], color=["tab:green", "tab:orange", "tab:gray"][: len(kinds)])
    for bar, k in zip(bars, kinds):
        ax0.text(bar.get_x() + bar.get_width() / 2, bar.get_height() + 0.02, f"{rates[k]:.2f}\n(n={counts[k]})",
                 ha="center", va="bottom", fontsize=8)
    ax0.set_ylim(0, 1.25)
    ax0.set_ylabel("success rate (simulated)")
    ax0.set_title(f"{task}: plans executed on randomised scenes")
    top = max([float(np.max(v)) for v in measures.values() if len(v)] + [1e-6])
    bins = np.linspace(0.0, top, 26)  # shared bins, so the kinds compare bar for bar
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
    plt.close(fig)
    return out
