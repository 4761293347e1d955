"""Benchmark: the LeRobot export (no video) with lerobot's own writes against ``fast_writes``, seconds per episode.

Makes ``--demos`` demos of ``--task`` (its expert plan on scenes 0, 1, ...; not timed), or takes the ``ep*.npz`` of
``--demo-dir``, then exports them side by side, alternating, ``--rounds`` times: ``fast_writes=False`` (lerobot's
per-frame image embedding and per-episode statistics, frames added one by one); ``fast_writes=True`` with lerobot's
statistics code and lerobot's per-episode stats.json and fingerprint (no embedding: there is no image to embed; each
episode handed to lerobot whole, ``prl.export._episode_buffer``); the same with the
statistics by ``prl.episode_stats``; and ``fast_writes=True`` (also ``prl.export._lean_writes``: stats.json once,
no fingerprint hashing, the numeric columns handed to ``datasets`` as Arrow arrays); with ``--workers N`` (N > 1)
also ``fast_writes`` in N processes merged by lerobot (``export_lerobot(workers=N)``, at least
``prl.export_merge.PARALLEL_MIN_EPISODES`` episodes per process). Each export is the real one
(``prl.export.export_lerobot``: write, reload, validate, move into place). Prints the medians, their ratio, and
whether the datasets hold the same files as lerobot's writes (``prl.export_compare``: the same bytes, and for the
parquet files the same table and metadata but for the fingerprint that ``datasets.map`` stamps).
``python -m bench.bench_export [--task hammer] [--demos 40] [--rounds 2] [--demo-dir DIR] [--workers N]``
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import tempfile
import time
from pathlib import Path

from bench.bench_export_video import _demos
from prl.export_compare import dataset_files, differing_files


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="hammer")
    parser.add_argument("--demos", type=int, default=40, help="episodes per export")
    parser.add_argument("--rounds", type=int, default=2, help="alternating rounds; medians are printed")
    parser.add_argument("--demo-dir", default=None,
                        help="export the first --demos ep*.npz under this directory (its shards' too)")
    parser.add_argument("--workers", type=int, default=1, help="also fast_writes in this many processes (> 1)")
    parser.add_argument("--only-workers", action="store_true",
                        help="with --workers: only fast_writes in 1 process and in --workers (for many demos)")
    args = parser.parse_args()

    import prl.export  # heavy: lerobot, after the arguments are parsed
    from prl.export import export_lerobot

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        if args.demo_dir:
            paths = sorted(Path(args.demo_dir).rglob("ep*.npz"))[:args.demos]
            if not paths:
                raise SystemExit(f"no ep*.npz demos in {args.demo_dir!r}")
        else:
            paths, _, _ = _demos(args.task, args.demos, out / "demos")
        modes = ("lerobot's writes", "no image embedding", "+ prl statistics", "fast_writes")
        parallel = f"fast_writes, {args.workers} processes"
        modes += (parallel,) if args.workers > 1 else ()
        run_modes = (modes[3], parallel) if args.workers > 1 and args.only_workers else modes
        # what each fast mode leaves as lerobot does it: the middle modes isolate one change's share each
        left_out = {"no image embedding": ("fast_episode_stats", "_lean_writes"), "+ prl statistics": ("_lean_writes",)}
        times: dict[str, list[float]] = {m: [] for m in modes}
        files: dict[str, dict[str, object]] = {}
        for r in range(args.rounds):
            for mode in run_modes:
                root = out / f"ds-{modes.index(mode)}-{r}"
                saved = {name: getattr(prl.export, name) for name in left_out.get(mode, ())}
                for name in saved:
                    setattr(prl.export, name, contextlib.nullcontext)
                try:
                    t0 = time.perf_counter()
                    export_lerobot(paths, root, repo_id="prl/bench", fast_writes=mode != "lerobot's writes",
                                   workers=args.workers if mode == parallel else 1)
                    times[mode].append((time.perf_counter() - t0) / len(paths))
                finally:
                    for name, value in saved.items():
                        setattr(prl.export, name, value)
                files[mode] = dataset_files(root)
        med = {m: statistics.median(times[m]) for m in run_modes}
        print(f"{len(paths)} episodes, {args.rounds} rounds, median s per episode: "
              + ", ".join(f"{m} {med[m]:.3f}" for m in run_modes))
        if args.workers > 1:
            print(f"fast_writes in 1 process / in {args.workers}: {med[modes[3]] / med[parallel]:.2f}x")
            if args.only_workers:
                return
        print(f"ratios: lerobot's writes / fast_writes {med[modes[0]] / med[modes[3]]:.2f}x; each change, the mode "
              f"before / the mode with it: prl statistics {med[modes[1]] / med[modes[2]]:.2f}x, stats.json once, no "
              f"fingerprint, Arrow columns {med[modes[2]] / med[modes[3]]:.2f}x")
        for mode in modes[1:]:
            differ = differing_files(files[modes[0]], files[mode])
            print(f"{mode}: same files as lerobot's writes: "
                  + ("yes, all " + str(len(files[mode])) if not differ else "NO: " + ", ".join(differ)))

if __name__ == "__main__":
    main()
