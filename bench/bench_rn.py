"""Benchmark (not a test): RN training throughput (samples/s) with 1 and 2 torch threads, in one run.

Paper configuration (``RNConfig()``: Table I on a 1680-long input, batch 64, Eq 3 loss, Adam) on
synthetic data (normal features, uniform labels; the speed does not depend on the values).
Two paths, both measured for torch threads 1 and 2, interleaved over rounds in rotating order, the
first epoch of each ``train_rn`` call excluded as warm-up, medians reported:

(a) ``train_rn`` epochs as the pipeline runs them: minibatch steps plus the per-epoch training-set
    accuracy pass (``rn/epoch_s`` of the history);
(b) the bare optimiser steps (forward, Eq 3 loss, backward, Adam step) on the same batches.

Then the paper profile's training wall time (8,000 samples x 200 epochs) is extrapolated from (a).

    python -m bench.bench_rn [--samples 2048] [--epochs 3] [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

if __package__ in (None, ""):  # ``python bench/bench_rn.py``
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from prl.constants import RS_DIMS

IN_DIM = 1680
PAPER_SAMPLES = 8000
PAPER_EPOCHS = 200


def _data(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, IN_DIM)).astype(np.float32)
    y = np.stack([rng.integers(0, m, n) for m in RS_DIMS], axis=1)
    return x, y


def measure_train_rn(x: np.ndarray, y: np.ndarray, epochs: int, seed: int) -> list[float]:
    """(a) samples/s of each ``train_rn`` epoch after the first (samples = batches x batch size)."""
    from prl.rn import RNConfig  # heavy: torch
    from prl.rn_train import train_rn

    cfg = RNConfig(epochs=epochs, seed=seed)
    _, history = train_rn(x, y, cfg, progress=False)
    per_epoch = (len(x) // cfg.batch_size) * cfg.batch_size
    return [per_epoch / r["rn/epoch_s"] for r in history[1:]]


def measure_steps(x: np.ndarray, y: np.ndarray, steps: int, seed: int) -> float:
    """(b) samples/s of bare optimiser steps (one warm-up step excluded)."""
    import torch  # heavy: torch

    from prl.rn import RepresentationNetwork, RNConfig, rn_loss, split_logits

    cfg = RNConfig(seed=seed)
    torch.manual_seed(seed)
    model = RepresentationNetwork(IN_DIM, cfg.dims)
    model.train()
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    xt, yt = torch.from_numpy(x), torch.from_numpy(y)
    bs = cfg.batch_size
    n_batches = len(x) // bs

    def step(k: int) -> None:
        sl = slice((k % n_batches) * bs, (k % n_batches + 1) * bs)
        terms = rn_loss(split_logits(model(xt[sl]), cfg.dims), yt[sl], cfg)
        opt.zero_grad(set_to_none=True)
        terms["total"].backward()
        opt.step()

    step(0)
    t0 = time.perf_counter()
    for k in range(1, steps + 1):
        step(k)
    return steps * bs / (time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=2048, help="training samples per train_rn call")
    parser.add_argument("--epochs", type=int, default=3, help="epochs per train_rn call (the first is warm-up)")
    parser.add_argument("--steps", type=int, default=64, help="bare optimiser steps per (b) measurement")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds of threads 1 and 2")
    args = parser.parse_args(argv)
    if args.epochs < 2:
        parser.error(f"--epochs must be >= 2 (the first epoch is warm-up), got {args.epochs}")

    import torch  # heavy: torch

    t_start = time.perf_counter()
    load0 = os.getloadavg()
    x, y = _data(args.samples, seed=0)
    threads = (1, 2)
    res: dict[tuple[str, int], list[float]] = {(k, t): [] for k in ("a", "b") for t in threads}
    before = torch.get_num_threads()
    try:
        for r in range(args.rounds):
            order = threads if r % 2 == 0 else threads[::-1]  # each thread count runs early and late
            for t in order:
                torch.set_num_threads(t)
                res[("a", t)] += measure_train_rn(x, y, args.epochs, seed=r)
                res[("b", t)].append(measure_steps(x, y, args.steps, seed=r))
    finally:
        torch.set_num_threads(before)
    load1 = os.getloadavg()

    med = {key: float(np.median(v)) for key, v in res.items()}
    print(f"\nRN training, paper config (Table I, in_dim {IN_DIM}, batch 64, Eq 3, Adam), torch {torch.__version__}, "
          f"{os.cpu_count()} CPUs; {args.samples} samples, {args.rounds} rounds")
    print(f"load average (1 min) at start {load0[0]:.2f}, at end {load1[0]:.2f} (other processes share the CPUs)")
    print(f"{'samples/s':<52} {'threads':>7} {'median':>8} {'min':>8} {'max':>8}  n")
    labels = {"a": "(a) train_rn epoch (steps + train-set accuracy pass)", "b": "(b) bare optimiser steps"}
    for kind in ("a", "b"):
        for t in threads:
            v = res[(kind, t)]
            print(f"{labels[kind]:<52} {t:>7} {med[(kind, t)]:>8.0f} {min(v):>8.0f} {max(v):>8.0f}  {len(v)}")
    for kind in ("a", "b"):
        print(f"speed-up 2 threads / 1 thread, {kind}: {med[(kind, 2)] / med[(kind, 1)]:.2f}x")
    best = max(threads, key=lambda t: med[("a", t)])
    per_epoch = (PAPER_SAMPLES // 64) * 64
    for t in threads:
        hours = PAPER_EPOCHS * per_epoch / med[("a", t)] / 3600
        print(f"extrapolated paper profile ({PAPER_SAMPLES:,} samples x {PAPER_EPOCHS} epochs, no validation set) "
              f"with {t} thread{'s' if t > 1 else ''}: {hours * 60:.1f} min{'  <- faster' if t == best else ''}")
    print(f"total bench time {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
