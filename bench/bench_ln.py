"""Benchmark (not a test): LN timesteps per second with 2 plan environments in parallel against 1, in one run.

Each measurement is ``model.learn`` of a fresh paper-setting A2C (``prl.ln.LNConfig``) for ``--timesteps``
plan episodes on the hammer (``envs.plan_env``: reset + observation + x + one whole plan episode per
timestep, one A2C update per 64). The vector env is built and warmed up (one reset) before the clock
starts, so subprocess start-up is excluded. 1 and 2 environments alternate over ``--rounds`` in
rotating order; the medians and their ratio are printed, then the paper-scale LN run (3200 timesteps)
and the hammer Fig 8 sweep (3 seeds x {K=0, K=1280, BC K=1280}, each 3200 timesteps, points run one
per core) are extrapolated from the faster setting.

    python -m bench.bench_ln [--timesteps 64] [--rounds 2] --pointnet outputs/models/pointnet-*.pt
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

if __package__ in (None, ""):  # ``python bench/bench_ln.py``
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from prl.config import LNConfig


def measure(n_envs: int, timesteps: int, pointnet: Path, seed: int) -> float:
    """Timesteps per second of ``learn`` with ``n_envs`` plan environments (start-up excluded)."""
    from envs.plan_env import PlanEnv
    from envs.tasks import fast_resets  # heavy: loads the simulator
    from envs.vec_env import make_vec_env
    from prl.ln import make_ln

    env = make_vec_env(PlanEnv, "hammer", n_envs, run_seed=seed, pointnet_path=pointnet)
    try:
        model = make_ln(env, LNConfig(n_envs=n_envs, seed=seed), np.zeros(1680), np.ones(1680))
        with fast_resets():
            env.reset()  # warm-up: scenes built, models loaded
            t0 = time.perf_counter()
            model.learn(total_timesteps=timesteps)
            return model.num_timesteps / (time.perf_counter() - t0)
    finally:
        env.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pointnet", required=True, type=Path, help="a PointNet checkpoint (models/pointnet-*.pt)")
    parser.add_argument("--timesteps", type=int, default=64)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args(argv)
    if not args.pointnet.is_file():
        parser.error(f"no PointNet checkpoint at {str(args.pointnet)!r}")
    rates: dict[int, list[float]] = {1: [], 2: []}
    for r in range(args.rounds):
        for n in ((1, 2) if r % 2 == 0 else (2, 1)):
            rates[n].append(measure(n, args.timesteps, args.pointnet, seed=r))
            print(f"round {r}: {n} env(s) {rates[n][-1]:.2f} timesteps/s", flush=True)
    one, two = float(np.median(rates[1])), float(np.median(rates[2]))
    print(f"\nmedian timesteps/s: 1 env {one:.2f}, 2 envs {two:.2f}; ratio 2/1 = {two / one:.2f}x")
    best, paper = max(one, two), LNConfig().timesteps
    print(f"paper-scale LN run ({paper} timesteps): {paper / best / 60:.0f} min at {best:.2f} timesteps/s")
    print(f"hammer Fig 8 sweep, 9 plan-env points x {paper} timesteps, one point per core on 2 cores: "
          f"{9 * paper / one / 2 / 3600:.1f} h (joint-control points and evaluations not included)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
