"""lerobot's per-episode statistics, computed the same way without its dense histograms.

Every ``save_episode`` of a lerobot 0.6 dataset computes, per feature, min, max, mean, std and five quantiles
(``lerobot.datasets.compute_stats.RunningQuantileStats``, one ``update`` with the episode's frames): per
dimension, 5,001 bin edges by ``np.linspace`` between the minimum and the maximum (padded by 1e-10), a
5,000-bin histogram by ``np.histogram``, and each quantile read from a fresh ``np.cumsum`` of that histogram. For
a demo's 17 features (about 1,000 dimensions) and 150 frames that is about 1,000 ``linspace`` calls and 5,000
cumulative sums of 5,000 bins an episode, most of the export's time (cProfile of 40 hammer demos, 2026-12-02:
0.23 s of a 0.38 s ``save_episode``).

``fast_episode_stats()`` makes ``get_feature_stats`` use :class:`SparseQuantileStats` for the duration of a block:
a ``RunningQuantileStats`` whose first ``update`` keeps each value's bin instead of a histogram (an episode's
150 values occupy at most 150 of the 5,000 bins) and whose quantiles are read from those bins. The numbers are
lerobot's bit for bit (``tests/prl/test_episode_stats.py`` compares them on the dtypes and edge cases a dataset
has):

- the edges (``LinEdges``): never all made; each edge that is read is computed by ``linspace``'s own arithmetic,
  in the same dtype and order, with the branch ``linspace`` takes for that dimension's call;
- a value's bin (``value_bins``): ``np.histogram``'s rule (a bin holds ``edges[j] <= v < edges[j + 1]``, the last
  one also its right edge), guessed from the value's place between the ends and moved until those two edges hold
  it; a dimension where that does not settle in a few moves is searched in its full edges. (A feature holding NaN
  has NaN edges, and lerobot's histogram of it means nothing; a demo's frames are finite.)
- a quantile ``q``: lerobot's first bin whose cumulative count reaches ``target = q * count``. Counts are integers,
  so that is the bin of the ``ceil(target)``-th smallest counted value; the counts before it and in it are
  counted from the sorted bins, and lerobot's interpolation is applied element for element in the same dtypes,
  for all dimensions at once.

A second ``update`` (lerobot's running use; not an episode's) first builds the dense histograms from the kept bins
and then runs lerobot's own code.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator

import numpy as np


class LinEdges:
    """The bin edges ``np.linspace(lo[i], hi[i], n + 1)`` of each dimension ``i``, by their formula, without making
    them: ``at(j)[..., i]`` is edge ``j[..., i]`` of dimension ``i``, the value ``linspace`` gives, bit for bit. ``linspace``
    computes ``j * step + lo`` in the edges' dtype with ``step = (hi - lo) / n`` (``(j / n) * (hi - lo) + lo``
    where the step is 0) and sets the last edge to ``hi``; each call of lerobot's is one dimension's, so the branch is
    the dimension's own (``tests/prl/test_episode_stats.py`` checks ``at`` against ``linspace``)."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, n: int) -> None:
        self.dtype = np.result_type(lo, hi, 1.0)
        self.lo, self.hi, self.n = lo.astype(self.dtype), hi.astype(self.dtype), n
        self.delta = np.subtract(self.hi, self.lo, dtype=self.dtype)
        self.step = self.delta / n
        self.flat = self.step == 0

    def at(self, j: np.ndarray) -> np.ndarray:
        """Edge ``j[..., i]`` of dimension ``i`` (``j``: integers, its last axis the dimensions)."""
        jf = np.asarray(j).astype(self.dtype)
        y = np.where(self.flat, (jf / self.n) * self.delta, jf * self.step) + self.lo
        return np.where(np.asarray(j) == self.n, self.hi, y).astype(self.dtype)

    def row(self, i: int) -> np.ndarray:
        """All edges of dimension ``i``: lerobot's own call."""
        return np.linspace(self.lo[i], self.hi[i], self.n + 1)


def value_bins(batch: np.ndarray, edges: LinEdges, max_steps: int = 4) -> np.ndarray:
    """(N, D) int64: the histogram bin of each value of ``batch`` (N, D) over ``edges``, ``np.histogram``'s rule
    (``edges[j] <= v < edges[j + 1]``, the last bin also its right edge); ``n`` (one past the last bin) for a value in
    none (outside the edges).

    Each value's bin is guessed from its place between the ends and moved until its edges hold it (at most
    ``max_steps`` moves); a dimension whose values are not all placed so (edges that repeat, where the dtype cannot
    tell ``hi - lo`` in 5,000 parts apart) is searched in its full edges instead. Where the ends are equal (a
    constant dimension whose padding the dtype cannot hold), every edge is that value and so is every value: the
    last bin, as ``np.histogram`` puts a value equal to the last edge."""
    n = edges.n
    d = batch.shape[1]
    lo, hi = edges.lo.astype(np.float64), edges.hi.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        guess = np.floor((batch.astype(np.float64) - lo) / (hi - lo) * n)
    j = np.clip(np.nan_to_num(guess, nan=0.0), 0, n - 1).astype(np.int64)
    j[:, edges.delta == 0] = n - 1
    for _ in range(max_steps):
        down = (batch < edges.at(j)) & (j > 0)
        up = (batch >= edges.at(j + 1)) & (j < n - 1)
        if not (down.any() or up.any()):
            break
        j = j - down + up
    first, last = edges.at(np.zeros(d, np.int64)), edges.at(np.full(d, n))
    j[(batch < first) | (batch > last)] = n
    placed = (j == n) | ((edges.at(np.minimum(j, n - 1)) <= batch) & ((batch < edges.at(np.minimum(j + 1, n)))
                                                                     | (j == n - 1)))
    for i in np.flatnonzero(~placed.all(axis=0)):
        row, values = edges.row(int(i)), batch[:, i]
        idx = np.searchsorted(row, values, side="right") - 1
        idx[values == row[-1]] = n - 1
        idx[(idx < 0) | (idx >= n)] = n
        j[:, i] = idx
    return j


def quantiles(bins: np.ndarray, edges: LinEdges, count: int, quantile_list: list[float]) -> list[np.ndarray]:
    """lerobot's ``RunningQuantileStats._compute_quantiles`` from each value's bin (``value_bins``) instead of the
    histograms: per quantile, one value per dimension."""
    n = edges.n
    d = bins.shape[1]
    ordered = np.sort(bins, axis=0)  # the bins of each dimension's counted values first, then the uncounted (n)
    counted = (ordered < n).sum(axis=0)
    first, last = edges.at(np.zeros(d, np.int64)), edges.at(np.full(d, n))
    out = []
    for q in quantile_list:
        target = q * count
        m = math.ceil(target) if target > 0 else 0  # the first bin whose cumulative count is >= target holds it
        reached = (m >= 1) & (m <= counted)
        at = ordered[min(max(m - 1, 0), ordered.shape[0] - 1)] if ordered.shape[0] else np.zeros(d, np.int64)
        at = np.where(reached, at, np.where(m >= 1, n, 0))  # lerobot's index into the cumulative sums
        before = (ordered < at[None, :]).sum(axis=0).astype(np.float64)
        in_bin = (ordered == at[None, :]).sum(axis=0).astype(np.float64)
        safe = np.clip(at, 0, n - 1)
        lo, hi = edges.at(safe), edges.at(safe + 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inner = lo + (target - before) / in_bin * (hi - lo)
        is_edge = (at == 0) | (at >= n) | (in_bin == 0)
        edge = np.where(at == 0, first, np.where(at >= n, last, lo))
        values = np.where(is_edge, edge, inner)
        # lerobot assembles numpy scalars: float64 as soon as one value is interpolated, else the edges' dtype
        out.append(values.astype(edges.dtype) if is_edge.all() else values.astype(np.float64))
    return out


def _sparse_class() -> type:
    from lerobot.datasets.compute_stats import RunningQuantileStats  # heavy: lerobot

    class SparseQuantileStats(RunningQuantileStats):
        """``RunningQuantileStats`` whose first ``update`` keeps each value's bin (``value_bins``) instead of dense
        histograms, and whose quantiles come from those bins (``quantiles``)."""

        _bins: np.ndarray | None = None
        _edges: LinEdges | None = None

        def update(self, batch: np.ndarray) -> None:
            if self._count != 0:  # a running update: lerobot's, on dense histograms
                self._densify()
                super().update(batch)
                return
            batch = batch.reshape(-1, batch.shape[-1])
            batch = batch.astype(np.result_type(batch.dtype, np.float32), copy=False)
            # lerobot's first update, but for the histograms; lerobot takes each mean twice (the start, then the
            # batch's), equal arrays, so each is taken once here and its running step kept (inf - inf is NaN there too)
            mean, mean_of_squares = np.mean(batch, axis=0), np.mean(batch**2, axis=0)
            self._mean, self._mean_of_squares = mean.copy(), mean_of_squares.copy()
            self._min = np.min(batch, axis=0)
            self._max = np.max(batch, axis=0)
            self._edges = LinEdges(self._min - 1e-10, self._max + 1e-10, self._num_quantile_bins)
            self._count += batch.shape[0]
            self._mean += (mean - self._mean) * (batch.shape[0] / self._count)
            self._mean_of_squares += (mean_of_squares - self._mean_of_squares) * (batch.shape[0] / self._count)
            self._bins = value_bins(batch, self._edges)

        def _densify(self) -> None:
            if self._bins is None:
                return
            n = self._num_quantile_bins
            self._histograms = [np.bincount(b[b < n], minlength=n).astype(np.float64) for b in self._bins.T]
            self._bin_edges = [self._edges.row(i) for i in range(len(self._histograms))]
            self._bins = None

        def _compute_quantiles(self) -> list[np.ndarray]:
            if self._bins is None:
                return super()._compute_quantiles()
            return quantiles(self._bins, self._edges, self._count, self._quantile_list)

    return SparseQuantileStats


@contextlib.contextmanager
def fast_episode_stats() -> Iterator[None]:
    """Within the block, lerobot's ``get_feature_stats`` (and so ``compute_episode_stats``) uses
    ``SparseQuantileStats``; lerobot's class is restored afterwards."""
    from lerobot.datasets import compute_stats  # heavy: lerobot

    saved = compute_stats.RunningQuantileStats
    compute_stats.RunningQuantileStats = _sparse_class()
    try:
        yield
    finally:
        compute_stats.RunningQuantileStats = saved
