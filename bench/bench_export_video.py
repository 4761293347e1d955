"""Benchmark: the LeRobot export with the cameras' video against the export without, seconds per episode.

Makes ``--demos`` demos of ``--task`` (its expert plan on scenes 0, 1, ...; not timed), then exports them
side by side, alternating, ``--rounds`` times: without video, and with video at each of ``--fps`` camera
pictures per second (``--size`` pixels square). Each export is the real one (``prl.export.export_lerobot``:
write, reload, validate, move into place); the video ones replay every demo with ``envs.video.DemoRenderer``
and encode with lerobot's default codec. The renderer's one-off cost per process (Vulkan shaders compiled on
the first picture, about 6 s on lavapipe) is measured apart and left out of the per-episode figures. Prints
medians, the ratio to the export without video, the part spent rendering, the dataset sizes, what the
quick and paper profiles' exports would add, and what recording the scene's moving bodies (``envs.scene_record``,
needed for the replay) adds to each synthesised episode.
``python -m bench.bench_export_video [--task hammer] [--demos 6] [--rounds 2] [--size 128] [--fps 10,50]``
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path


def _demos(task: str, n: int, out: Path) -> tuple[list[Path], float, int]:
    """The demos, and what the scene record adds to an episode: seconds per record, bodies recorded."""
    import envs  # noqa: F401  (heavy: registers the hand and the tasks in the simulator)
    from envs.executor import PlanExecutor
    from envs.scene_record import SceneParts
    from envs.tasks import make_env, task_class
    from prl.demo import from_episode, save_demo
    from prl.plb import load_plb

    text = load_plb().texts(task)[0]
    env = make_env(task)
    try:
        executor = PlanExecutor(env)
        paths = [save_demo(from_episode(task, seed, text, executor.run(task_class(task).expert_plan, seed=seed), env),
                           out / f"ep{seed}.npz") for seed in range(n)]
        parts = SceneParts(env)
        t0 = time.perf_counter()
        for _ in range(1000):  # what envs.episode reads at every record for a replay
            parts.poses()
            parts.qpos()
        return paths, (time.perf_counter() - t0) / 1000, len(parts.bodies)
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="hammer")
    parser.add_argument("--demos", type=int, default=6, help="episodes per export")
    parser.add_argument("--rounds", type=int, default=2, help="alternating rounds; medians are printed")
    parser.add_argument("--size", type=int, default=128, help="picture width and height, pixels")
    parser.add_argument("--fps", default="10,50", help="camera pictures per second to compare, comma-separated")
    args = parser.parse_args()

    import datasets  # heavy (pyarrow, pandas): after the arguments are parsed

    from envs.video import DemoRenderer  # heavy: the simulator and its renderer
    from prl.demo import load_demo
    from prl.export import export_lerobot
    from prl.export_schema import VideoSpec

    fps_list = [int(v) for v in args.fps.split(",")]
    specs = {None: None, **{f: VideoSpec(width=args.size, height=args.size, fps=f) for f in fps_list}}
    times: dict[int | None, list[float]] = {k: [] for k in specs}
    render_s: dict[int | None, list[float]] = {k: [] for k in specs}
    sizes: dict[int | None, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        datasets.config.HF_DATASETS_CACHE = str(tmp_path / "hf_cache")  # reloads' Arrow copies stay in tmp
        paths, record_s, bodies = _demos(args.task, args.demos, tmp_path / "demos")
        frames = sum(len(load_demo(p).stage) for p in paths)
        with DemoRenderer(VideoSpec(width=args.size, height=args.size)) as render:
            t0 = time.perf_counter()
            render(load_demo(paths[0]), [0])
            first = time.perf_counter() - t0
            for r in range(args.rounds):
                for key, spec in specs.items():
                    root = tmp_path / f"ds-{key}-{r}"
                    t0 = time.perf_counter()
                    report = export_lerobot(paths, root, repo_id=f"prl/{args.task}", video=spec,
                                            render_images=render if spec is not None else None)
                    times[key].append((time.perf_counter() - t0) / args.demos)
                    render_s[key].append(report.video_seconds / args.demos)
                    sizes[key] = report.size_bytes
    base = statistics.median(times[None])
    print(f"\n{args.task}: {args.demos} episodes ({frames // args.demos} frames at 50 fps each), {args.rounds} rounds, "
          f"medians; pictures {args.size}x{args.size}, 2 cameras")
    print(f"first picture in a process (shader compilation, once per export run): {first:.1f} s")
    print(f"recording the scene's {bodies} moving bodies for the replay: {record_s * 1e6:.1f} us per record, "
          f"{record_s * frames / args.demos * 1e3:.2f} ms per episode during synthesis")
    print(f"{'export':>22} {'s/episode':>10} {'x no video':>11} {'rendering s/ep':>15} {'MB/episode':>11}")
    for key in specs:
        label = "no video" if key is None else f"video {key} pictures/s"
        med = statistics.median(times[key])
        print(f"{label:>22} {med:>10.3f} {med / base:>11.2f} {statistics.median(render_s[key]):>15.3f} "
              f"{sizes[key] / args.demos / 1e6:>11.3f}")
    for key in fps_list:
        extra = statistics.median(times[key]) - base
        print(f"video {key} pictures/s adds {extra:.2f} s per episode: quick profile (4 tasks x 4 demos) "
              f"+{16 * extra + first:.0f} s, paper profile (4 tasks x 2,000 demos) +{8000 * extra / 60:.0f} min")


if __name__ == "__main__":
    main()
