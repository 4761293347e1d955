"""Statistics for few runs, after the rliable method (Agarwal et al., "Deep RL at the Edge of the Statistical
Precipice", NeurIPS 2021): the interquartile mean, stratified-bootstrap confidence intervals and the probability
of improvement. Pure numpy; every resampling draws from ``numpy.random.default_rng(seed)`` in a fixed order, so
the same inputs and seed give the same interval on any machine.

Scores come as ``{task: [run, run, ...]}``, each run the per-scene successes (or scores) of one seed's final
policy on the evaluation scenes; a run's score is their mean (its success fraction). The bootstrap resamples the
runs of each task (the stratum) with replacement, independently per task, as rliable's ``StratifiedBootstrap``
does; with ``resample_scenes`` each drawn run's scenes are resampled with replacement as well (two-level: seeds,
then scenes within each seed), so that an interval also carries the evaluation's finite number of scenes.
Intervals are the bootstrap distribution's percentiles (rliable's default ``percentile`` method).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

RunsByTask = Mapping[str, Sequence[Sequence[float]]]
"""Per task, one sequence of per-scene scores per run (seed)."""


def iqm(scores: Sequence[float] | np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """Interquartile mean: the mean of the scores left after cutting ``int(0.25 n)`` from each end of the sorted
    scores (``axis=None``: all scores, flattened). This is ``scipy.stats.trim_mean(scores, 0.25)``, which is what
    rliable's ``aggregate_iqm`` computes: whole scores are cut, none is weighted fractionally (for 8 scores the
    middle 4; for 3 the cut is 0 and the IQM is the mean). ValueError on no score."""
    a = np.asarray(scores, dtype=float)
    if axis is None:
        a, axis = a.reshape(-1), 0
    a = np.moveaxis(a, axis, -1)
    n = a.shape[-1]
    if n == 0:
        raise ValueError("the interquartile mean of no score is undefined; give at least one")
    cut = int(0.25 * n)
    kept = np.sort(a, axis=-1)[..., cut:n - cut]
    out = kept.mean(axis=-1)
    return float(out) if out.ndim == 0 else out


def run_scores(runs_by_task: RunsByTask) -> dict[str, np.ndarray]:
    """Each run's score (the mean of its per-scene scores), per task. ValueError naming a task without runs or a
    run without scenes."""
    out = {}
    for task, runs in runs_by_task.items():
        if not len(runs):
            raise ValueError(f"task {task!r} has no run; give at least one per task")
        for i, run in enumerate(runs):
            if not len(run):
                raise ValueError(f"task {task!r}: run {i} has no scene score")
        out[task] = np.array([float(np.mean(np.asarray(run, dtype=float))) for run in runs])
    return out


def _check(reps: int, level: float) -> None:
    if isinstance(reps, bool) or not isinstance(reps, int) or reps < 1:
        raise ValueError(f"reps must be an integer >= 1, got {reps!r}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level!r}")


def _resampled_scores(runs: Sequence[Sequence[float]], reps: int, rng: np.random.Generator,
                      resample_scenes: bool) -> np.ndarray:
    """(reps, n_runs) scores of the runs of one task, drawn with replacement (and their scenes, if asked)."""
    arrays = [np.asarray(run, dtype=float) for run in runs]
    n = len(arrays)
    idx = rng.integers(0, n, size=(reps, n))
    means = np.array([a.mean() for a in arrays])
    if not resample_scenes:
        return means[idx]
    out = np.empty((reps, n))
    for i, a in enumerate(arrays):  # every draw of run i gets its own resample of run i's scenes
        hit = idx == i
        count = int(hit.sum())
        if count:
            out[hit] = a[rng.integers(0, a.size, size=(count, a.size))].mean(axis=1)
    return out


def _interval(values: np.ndarray, level: float) -> tuple[float, float]:
    tail = 100.0 * (1.0 - level) / 2.0
    lo, hi = np.percentile(values, [tail, 100.0 - tail])
    return float(lo), float(hi)


def stratified_bootstrap_ci(runs_by_task: RunsByTask, statistic: Callable[..., np.ndarray] = iqm,
                            reps: int = 10_000, seed: int = 0, resample_scenes: bool = True,
                            level: float = 0.95) -> tuple[float, float, float]:
    """``(estimate, low, high)``: ``statistic`` of all run scores pooled over tasks, and its ``level``
    stratified-bootstrap interval (runs resampled within each task; scenes within each run when
    ``resample_scenes``). ``statistic(matrix, axis=-1)`` reduces each row of a (reps, runs) matrix, as ``iqm``
    does; tasks in the mapping's order (the draws depend on it)."""
    _check(reps, level)
    scores = run_scores(runs_by_task)
    estimate = float(statistic(np.concatenate(list(scores.values()))[None, :], axis=-1)[0])
    rng = np.random.default_rng(seed)
    drawn = np.concatenate([_resampled_scores(runs, reps, rng, resample_scenes) for runs in runs_by_task.values()],
                           axis=1)
    return (estimate, *_interval(np.asarray(statistic(drawn, axis=-1), dtype=float), level))


def improvement_probability(x: Sequence[float], y: Sequence[float]) -> float:
    """P(X > Y) of one task: the Mann-Whitney U statistic of run scores ``x`` against ``y`` over ``len(x) len(y)``,
    i.e. the share of pairs (x_i, y_j) with x_i > y_j, a tie counting 1/2. ValueError on an empty side."""
    a, b = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if not a.size or not b.size:
        raise ValueError(f"P(X > Y) needs runs on both sides, got {a.size} and {b.size}")
    return float(_pairwise(a[None, :], b[None, :])[0])


def _pairwise(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise U / (n m) of (reps, n) against (reps, m)."""
    diff = a[:, :, None] - b[:, None, :]
    return ((diff > 0).sum(axis=(1, 2)) + 0.5 * (diff == 0).sum(axis=(1, 2))) / (a.shape[1] * b.shape[1])


def probability_of_improvement(x_by_task: RunsByTask, y_by_task: RunsByTask, reps: int = 10_000, seed: int = 0,
                               resample_scenes: bool = True, level: float = 0.95) -> tuple[float, float, float]:
    """``(estimate, low, high)``: rliable's probability of improvement of X over Y, the mean over tasks of each
    task's ``improvement_probability`` of the run scores, with its ``level`` bootstrap interval (the runs of X and
    of Y resampled independently within each task, and their scenes when ``resample_scenes``). Both mappings must
    name the same tasks (ValueError naming the difference); tasks in ``x_by_task``'s order."""
    _check(reps, level)
    if set(x_by_task) != set(y_by_task):
        raise ValueError(f"X and Y must cover the same tasks: X has {sorted(x_by_task)}, Y {sorted(y_by_task)}")
    if not x_by_task:
        raise ValueError("no task to compare; give at least one")
    xs, ys = run_scores(x_by_task), run_scores(y_by_task)
    estimate = float(np.mean([improvement_probability(xs[t], ys[t]) for t in x_by_task]))
    rng = np.random.default_rng(seed)
    per_task = []
    for t in x_by_task:
        a = _resampled_scores(x_by_task[t], reps, rng, resample_scenes)
        b = _resampled_scores(y_by_task[t], reps, rng, resample_scenes)
        per_task.append(_pairwise(a, b))
    return (estimate, *_interval(np.mean(per_task, axis=0), level))
