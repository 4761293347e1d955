"""A LeRobot dataset written by several processes (``prl.export.export_lerobot(workers=N)``): contiguous parts of
its episodes written as datasets of their own at once, then merged in order by lerobot's ``aggregate_datasets``.

The merge renumbers the episode, frame and task indices in the data and in each episode's statistics; it
aggregates ``meta/stats.json`` from the parts' own, whose index statistics count from 0 in each part, so those are
aggregated again from the episodes' (``_index_stats_from_episodes``). The result holds the episodes, frames,
tasks and scene records one process writes, and its statistics up to float rounding
(``tests/prl/test_export.py``); the parquet files are lerobot's merge's.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import shutil
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from prl.export_schema import SCENES_FILE

PARALLEL_MIN_EPISODES = 100
"""Episodes per worker below which ``export_lerobot`` writes in one process: a worker process's start (imports of
lerobot and torch, a few seconds) costs what some tens of episodes take to write (0.15-0.3 s each)."""


def export_parts(n_episodes: int, workers: int, min_per_worker: int | None = None) -> list[range]:
    """The contiguous ranges of episode indices that ``workers`` processes write, as even as they can be (the first
    ones one longer); fewer parts when a part would hold under ``min_per_worker`` episodes (default
    ``PARALLEL_MIN_EPISODES``), one part at least."""
    floor = PARALLEL_MIN_EPISODES if min_per_worker is None else min_per_worker
    k = max(1, min(workers, n_episodes // max(1, floor)))
    sizes = [n_episodes // k + (1 if i < n_episodes % k else 0) for i in range(k)]
    starts = np.cumsum([0, *sizes])
    return [range(int(a), int(b)) for a, b in itertools.pairwise(starts)]


def write_parallel(write_part: Callable[..., list[Any]], parts: Sequence[Sequence[Path]], staging: Path, repo_id: str,
                   fps: int, labels: Mapping[Any, Any] | None, fast: bool) -> list[Any]:
    """Write each of ``parts`` (the demos of contiguous episodes, in order) in its own process with
    ``write_part(part, root, repo_id, fps, labels, fast)`` (``prl.export._write_part``: a dataset at ``root``, its
    episodes' checks returned) under a sibling of ``staging`` (``.<name>.staging-parts-<pid>``, which a later
    export cleans up if this one is killed), then merge them in order into ``staging`` with lerobot's
    ``aggregate_datasets`` (episode, frame and task indices renumbered, statistics aggregated) and the scene
    records renumbered. A progress bar counts the episodes the parts have written (``part_episode_written``).
    Returns the episodes' checks, in order."""
    import multiprocessing  # heavy: only for a parallel export
    from concurrent.futures import ProcessPoolExecutor, wait

    from lerobot.datasets.aggregate import aggregate_datasets  # heavy (pandas, lerobot): only when merging

    work = staging.parent / staging.name.replace(".staging-", ".staging-parts-")
    shutil.rmtree(work, ignore_errors=True)
    roots = [work / f"part{i}" for i in range(len(parts))]
    context = multiprocessing.get_context("spawn")
    written = context.Value("i", 0)
    try:
        with ProcessPoolExecutor(len(parts), mp_context=context, initializer=_count_into, initargs=(written,)) as pool, \
                tqdm(total=sum(len(p) for p in parts), desc=f"export ({len(parts)} processes)", unit="episode") as bar:
            futures = [pool.submit(write_part, list(part), part_root, repo_id, fps, labels, fast)
                       for part, part_root in zip(parts, roots, strict=True)]
            while wait(futures, timeout=1.0).not_done:
                bar.update(written.value - bar.n)
            bar.update(written.value - bar.n)
            checks = [c for f in futures for c in f.result()]
        with step(f"export: merging the {len(roots)} parts' {len(checks):,} episodes"):
            with _quiet_aggregate():
                aggregate_datasets([repo_id] * len(roots), repo_id, roots=roots, aggr_root=staging)
            _index_stats_from_episodes(staging)
            scenes = []
            for part_root in roots:
                for line in (part_root / SCENES_FILE).read_text().splitlines():
                    scenes.append({**json.loads(line), "episode_index": len(scenes)})
            with open(staging / SCENES_FILE, "w") as fh:
                fh.writelines(json.dumps(row) + "\n" for row in scenes)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return checks


_PART_COUNT: Any = None
"""In a part's process of ``write_parallel``: the count of the episodes the parts have written, shared with the
process that shows it (a ``multiprocessing.Value``, handed over by the pool's initializer)."""


def _count_into(count: Any) -> None:
    global _PART_COUNT  # the pool's initializer: the one way a spawned process receives a shared Value
    _PART_COUNT = count


def part_episode_written() -> None:
    """One more episode written by this part's process, for ``write_parallel``'s progress bar (a no-op in any other
    process)."""
    if _PART_COUNT is not None:
        with _PART_COUNT.get_lock():
            _PART_COUNT.value += 1


INDEX_FEATURES: tuple[str, ...] = ("episode_index", "index", "task_index")
"""The features a part numbers from 0 and the merge renumbers: lerobot 0.6's ``aggregate_datasets`` renumbers them
in the data and in each episode's statistics, but aggregates ``meta/stats.json`` from the parts' own."""


def _index_stats_from_episodes(root: Path) -> None:
    """``meta/stats.json`` of ``INDEX_FEATURES`` aggregated again (lerobot's ``aggregate_stats``, as a one-process
    write aggregates them episode by episode) from the merged episodes' statistics of them in ``meta/episodes``;
    the other features' statistics are the merge's."""
    import pandas as pd  # heavy: only after a merge
    from lerobot.datasets.compute_stats import aggregate_stats
    from lerobot.datasets.io_utils import load_stats, write_stats

    episodes = pd.concat([pd.read_parquet(f) for f in sorted((root / "meta" / "episodes").glob("*/*.parquet"))])
    columns = {f: [c for c in episodes.columns if c.startswith(f"stats/{f}/")] for f in INDEX_FEATURES}
    episodes = episodes[["episode_index", *(c for cols in columns.values() for c in cols)]]
    per_episode = [{f: {c.rsplit("/", 1)[1]: np.asarray(row[c]) for c in cols} for f, cols in columns.items()}
                   for _, row in episodes.sort_values("episode_index").iterrows()]
    stats = load_stats(root)
    stats.update(aggregate_stats(per_episode))
    write_stats(stats, root)


@contextlib.contextmanager
def step(what: str) -> Iterator[None]:
    """A line on stderr when ``what`` starts and one with its seconds when it ends: the export's steps after the
    episodes' progress bar (the merge, the reload check) took about 3.5 min of the paper profile's export with
    nothing on screen."""
    tqdm.write(f"{what} ...", file=sys.stderr)
    t0 = time.perf_counter()
    yield
    tqdm.write(f"{what}: done in {time.perf_counter() - t0:.1f} s", file=sys.stderr)


@contextlib.contextmanager
def _quiet_aggregate() -> Iterator[None]:
    """lerobot's ``aggregate_datasets`` without its progress bar and INFO lines."""
    import logging

    import tqdm  # heavy: only around a merge

    logger = logging.getLogger("lerobot.datasets.aggregate")
    level = logger.level
    logger.setLevel(logging.WARNING)
    original = tqdm.tqdm
    tqdm.tqdm = lambda *args, **kwargs: original(*args, **{**kwargs, "disable": True})
    try:
        yield
    finally:
        tqdm.tqdm = original
        logger.setLevel(level)
