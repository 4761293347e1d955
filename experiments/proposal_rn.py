"""Does the adaptive proposal change what the RN learns? Two pipeline runs of one task, side by side.

Issue #28's check of the weights (``prl.proposal``): an RN trained on demos synthesised with the adaptive proposal,
each weighted by prior / proposal, should learn what an RN trained on prior-only demos learns. Given the output
directories of two runs of ``python -m flows.full_pipeline --tasks T --train-rn`` that differ only in
``--proposal prior`` and ``--proposal adaptive``, this reads both datasets back (``lerobot``), encodes them with
their PointNet, and sets side by side four RNs:

- ``prior``: the prior run's RN (``models/rn-seed<S>.pt``), trained on unweighted prior-only demos;
- ``prior, another init seed``: an RN trained here on the same demos from another initialisation, the floor of
  what differs between two RNs of the same data;
- ``adaptive, weighted``: the adaptive run's RN, trained with the weights (what the pipeline does);
- ``adaptive, raw``: an RN trained here on the adaptive run's demos with the weights left out (same settings and
  split), to show what the weights correct.

Reported:

1. Fig 7's bars (each choice's mean predicted probability per dimension) on one common set of inputs, the prior
   run's held-out demos, and on each run's own held-out demos weighted as the pipeline draws Fig 7; per dimension
   the largest difference from the prior RN's bars (the target: < 0.1 with the weights);
2. each RN's argmax plan executed on the same unseen scenes (``envs.trials.eval_scene_seeds``), with 95% Wilson
   intervals (the target: the intervals of the weighted and the prior RN overlap);
3. the RNs' Fig 7 on the common inputs, one row each: ``<markdown stem>_fig7.png`` beside ``--markdown``, else
   ``<out>/proposal_rn_fig7.png`` (the RNs trained here are saved under ``--out``);
4. with ``--init-seeds K`` (K >= 2), the same bar differences for Fig 7 averaged over K RNs per side, each trained
   here from its own initialisation (seeds 0..K-1; the adaptive ones with the weights, as the pipeline trains them, and
   without), and the floor: the prior demos' mean over seeds 0..K-1 against their mean over seeds K..2K-1. One RN's
   bars move by up to 0.06-0.08 with its initialisation alone (2026-12-05), as much as the target leaves; averaging
   separates what the data do from what one initialisation does. A fifth row corrects the raw RNs' outputs by
   ``label_shift`` (each choice scaled by its weighted over raw frequency among the adaptive training demos), a
   correction the pipeline does not make.
5. with ``--second-prior-dir D`` (a prior-only run of the same task with another ``--seed``, ``--second-prior-seed``;
   both may be repeated, one pair per run): the floor of two datasets rather than two initialisations. Each such
   run's demos are encoded with the prior run's PointNet (the pipeline trains a PointNet per seed; only the demos
   should differ), an RN trained here on them from the prior RN's initialisation gets a row (bars on the common
   inputs and on its own held-out demos, argmax success), and with ``--init-seeds K`` the mean of K RNs trained here
   on them (seeds 0..K-1) a row of the averaged table. Two prior-only datasets of the same size differ by their
   scenes and by which plans happened to succeed; the adaptive run's gap means little unless it exceeds theirs.
   With ``--init-seeds K`` a last table sets the means of K RNs of each prior-only dataset and of the adaptive run
   against each prior-only one (``pairwise_gaps``): the first prior run is a sample too, and the spread among the
   prior-only runs is the floor the adaptive run is judged against.
6. with ``--pointnet P``: every run's demos are encoded with that PointNet (the profile's, which does not depend on the
   demos) and the ``prior`` and ``adaptive, weighted`` RNs are trained here too (init seed ``--seed``, the adaptive one
   with the weights), so the runs may be made with ``--no-train-rn``: a run of 2,000 demos, or the unscrew demos of a
   four-task paper run re-exported on their own, without the pipeline's RN stage. ``--adaptive-seed`` names the
   adaptive run's seed where it is not the prior run's (an adaptive run set against prior-only runs of new seeds).

``python -m experiments.proposal_rn --prior-dir P --adaptive-dir A --task hammer [--seed 0] [--adaptive-seed S]
[--scenes 50] [--init-seeds 5] [--second-prior-dir P2 --second-prior-seed 1 ...] [--pointnet models/pointnet-<key>.pt]
[--markdown <dir>/proposal_rn_hammer.md]``
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

if __package__ in (None, ""):  # ``python experiments/proposal_rn.py``
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from prl.config import PipelineConfig
from prl.stats import effective_sample_size, format_rate, wilson_interval


def bar_gaps(probs_a: Sequence[np.ndarray], probs_b: Sequence[np.ndarray],
             weights_a: Sequence[float] | None = None, weights_b: Sequence[float] | None = None) -> list[float]:
    """Per dimension, the largest absolute difference between the Fig 7 bars (weighted mean probability of each
    choice over the samples, ``prl.rn_decode.key_dimensions``) of two sets of per-dimension probabilities."""
    from prl.rn_decode import key_dimensions  # why: torch behind it, not needed for --help

    if len(probs_a) != len(probs_b):
        raise ValueError(f"{len(probs_a)} dimensions against {len(probs_b)}")
    bars_a = key_dimensions(probs_a, weights=weights_a)
    bars_b = key_dimensions(probs_b, weights=weights_b)
    return [float(np.abs(a.mean_probs - b.mean_probs).max()) for a, b in zip(bars_a, bars_b, strict=True)]


def mean_probs(runs: Sequence[Sequence[np.ndarray]]) -> list[np.ndarray]:
    """Per dimension, the element-wise mean of several RNs' (N, m_i) probabilities on the same N inputs."""
    return [np.mean([probs[i] for probs in runs], axis=0) for i in range(len(runs[0]))]


def pairwise_gaps(means: dict[str, Sequence[np.ndarray]], priors: dict[str, str], other: str, k: int) -> list[str]:
    """Report lines: the largest bar difference over all dimensions between the mean bars (of ``k`` RNs each) of every
    prior-only dataset (``priors``: column label -> key of ``means``) and of ``other``, each against each prior-only
    one. Any one prior-only run is a sample too; the spread among them is the floor ``other`` is judged against."""
    labels = list(priors)
    rows = {**priors, other: other}  # row label -> key of means
    gap = {(r, b): max(bar_gaps(means[rows[r]], means[priors[b]])) for r in rows for b in labels if r != b}
    lines = [(f"The largest bar difference (any dimension) between the means of {k} RNs of each dataset, against "
              f"each prior-only dataset:"), "", f"| mean of {k} RNs | {' | '.join(labels)} |",
             f"|---|{'---|' * len(labels)}"]
    for r in rows:
        lines.append(f"| {r} | " + " | ".join("-" if r == b else f"{gap[r, b]:.2f}" for b in labels) + " |")
    among = [gap[a, b] for i, a in enumerate(labels) for b in labels[i + 1:]]
    to_other = [gap[other, b] for b in labels]
    floor = (f"the two prior-only datasets: {among[0]:.2f}" if len(among) == 1 else
             f"prior-only datasets: {min(among):.2f}-{max(among):.2f} (median {float(np.median(among)):.2f}, "
             f"{len(among)} pairs)")
    lines += ["", (f"Between {floor}; {other} against them: {min(to_other):.2f}-{max(to_other):.2f} (median "
                   f"{float(np.median(to_other)):.2f}).")]
    return lines


def label_shift(probs: Sequence[np.ndarray], plans: np.ndarray, weights: np.ndarray) -> list[np.ndarray]:
    """Per dimension, (N, m_i) probabilities multiplied by each choice's weighted over raw frequency in ``plans``
    (K, n) with ``weights`` (K,), and renormalised: the label-shift correction of a classifier trained on the raw
    demos towards their weighted distribution (Saerens et al. 2002). A choice no plan holds keeps its factor 1."""
    out = []
    for i, pr in enumerate(probs):
        m = pr.shape[1]
        raw = np.bincount(plans[:, i], minlength=m) / len(plans)
        weighted = np.bincount(plans[:, i], weights=weights, minlength=m) / np.sum(weights)
        scaled = pr * np.where(raw > 0, weighted / np.maximum(raw, 1e-300), 1.0)
        out.append(scaled / scaled.sum(axis=1, keepdims=True))
    return out


def intervals_overlap(a: tuple[int, int], b: tuple[int, int]) -> bool:
    """Whether the 95% Wilson intervals of two (successes, n) overlap."""
    (lo_a, hi_a), (lo_b, hi_b) = wilson_interval(*a), wilson_interval(*b)
    return lo_a <= hi_b and lo_b <= hi_a


def dataset_inputs(run_dir: Path, task: str, seed: int) -> tuple[Path, str]:
    """(dataset root, repo id) of a pipeline run's output directory; FileNotFoundError if the dataset is missing."""
    repo = f"{task}-seed{seed}"
    root = run_dir / "datasets" / repo
    if not root.exists():
        raise FileNotFoundError(f"{root} not found: is {run_dir} the output of a pipeline run of {task!r} with "
                                f"--seed {seed}?")
    return root, f"prl/{repo}"


def run_inputs(run_dir: Path, task: str, seed: int,
               pointnet: Path | None = None) -> tuple[Path, str, Path, Path | None]:
    """(dataset root, repo id, PointNet, RN) of a pipeline run's output directory; FileNotFoundError naming what
    is missing. With ``pointnet`` given: that PointNet and no RN (one is trained here), the run's models unread."""
    root, repo = dataset_inputs(run_dir, task, seed)
    if pointnet is not None:
        return root, repo, pointnet, None
    rn = run_dir / "models" / f"rn-seed{seed}.pt"
    pointnets = sorted((run_dir / "models").glob("pointnet-*.pt"))
    if not rn.exists():
        raise FileNotFoundError(f"{rn} not found: is {run_dir} the output of a pipeline run of {task!r} with "
                                f"--train-rn and --seed {seed}?")
    if len(pointnets) != 1:
        raise FileNotFoundError(f"expected one PointNet in {run_dir / 'models'}, found {[p.name for p in pointnets]}")
    return root, repo, pointnets[0], rn


def main(argv: list[str] | None = None) -> int:
    # heavy: the simulator, trimesh, torch and lerobot behind these
    from envs.trials import eval_scene_seeds
    from flows.compute_features import rn_features
    from flows.evaluate_rn import rn_outcomes
    from prl.features import FEATURE_LAYOUT, split_by_seed
    from prl.plb import load_plb
    from prl.plots import plot_rn_probabilities
    from prl.rn import RNConfig
    from prl.rn_checkpoint import load_rn, save_rn
    from prl.rn_decode import predict_proba
    from prl.rn_train import train_rn

    defaults = PipelineConfig()
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--prior-dir", type=Path, required=True, help="output dir of the --proposal prior run")
    ap.add_argument("--adaptive-dir", type=Path, required=True, help="output dir of the --proposal adaptive run")
    ap.add_argument("--task", required=True)
    ap.add_argument("--seed", type=int, default=0, help="the runs' --seed")
    ap.add_argument("--adaptive-seed", type=int,
                    help="the adaptive run's --seed where it differs from the prior run's (default: --seed)")
    ap.add_argument("--scenes", type=int, default=50, help="unseen scenes each RN's plan is executed on")
    ap.add_argument("--rn-epochs", type=int, default=200, help="epochs of the raw RN (the paper profile's 200)")
    ap.add_argument("--val-fraction", type=float, default=defaults.rn_val_fraction)
    ap.add_argument("--out", type=Path, default=Path("outputs/experiments/proposal_rn"))
    ap.add_argument("--markdown", type=Path, help="also write the report to this file")
    ap.add_argument("--init-seeds", type=int, default=1,
                    help="K >= 2: also Fig 7 averaged over K RNs per side trained here (4K more RNs, K more per "
                         "--second-prior-dir)")
    ap.add_argument("--second-prior-dir", type=Path, action="append", default=[],
                    help="output dir of another --proposal prior run with another seed: the floor of two datasets "
                         "(repeat for several runs)")
    ap.add_argument("--second-prior-seed", type=int, action="append", default=[],
                    help="that run's --seed, one per --second-prior-dir (default: --seed + 1, + 2, ...)")
    ap.add_argument("--pointnet", type=Path,
                    help="encode every run with this PointNet and train the prior and adaptive RNs here too (runs "
                         "made with --no-train-rn)")
    args = ap.parse_args(argv)
    if args.pointnet is not None and not args.pointnet.is_file():
        ap.error(f"--pointnet {args.pointnet}: no such file")
    if args.init_seeds < 1:
        ap.error(f"--init-seeds must be >= 1, got {args.init_seeds}")
    second_seeds = args.second_prior_seed or [args.seed + 1 + i for i in range(len(args.second_prior_dir))]
    if len(second_seeds) != len(args.second_prior_dir):
        ap.error(f"{len(second_seeds)} --second-prior-seed for {len(args.second_prior_dir)} --second-prior-dir")
    if args.seed in second_seeds:
        ap.error(f"--second-prior-seed must differ from --seed ({args.seed}): the floor compares two datasets")
    if len(set(second_seeds)) < len(second_seeds):
        ap.error(f"--second-prior-seed {second_seeds}: each run's seed once")
    seconds = {f"prior, another dataset (seed {s}), trained here": (d, s)
               for d, s in zip(args.second_prior_dir, second_seeds, strict=True)}

    plb = load_plb()
    prior_in = run_inputs(args.prior_dir, args.task, args.seed, args.pointnet)
    adaptive_seed = args.seed if args.adaptive_seed is None else args.adaptive_seed
    adapt_in = run_inputs(args.adaptive_dir, args.task, adaptive_seed, args.pointnet)
    # name -> (dataset root, repo id, the PointNet that encodes it, the run's seed: the salt of the pipeline's split)
    runs = {"prior": (*prior_in[:3], args.seed), "adaptive": (*adapt_in[:3], adaptive_seed)}
    for second, (directory, s) in seconds.items():
        runs[second] = (*dataset_inputs(directory, args.task, s), prior_in[2], s)
    data = {}
    for name, (root, repo, pointnet, salt) in runs.items():
        d = rn_features(root, repo, pointnet, defaults.n_points)
        d["train"], d["val"] = split_by_seed(d["seeds"], args.val_fraction, salt=salt)
        data[name] = d
    p, a = data["prior"], data["adaptive"]
    args.out.mkdir(parents=True, exist_ok=True)

    trained: dict[tuple[int, int, bool], Path] = {}  # (demos, init seed, weighted) -> the RN already trained so

    def trained_here(d: dict, name: str, init_seed: int, weighted: bool = False) -> Path:
        """An RN trained here on ``d``'s training demos (with their weights or without), saved under ``--out``; the
        same demos, seed and weighting as an earlier one (training is deterministic) reuse its file."""
        key = (id(d), init_seed, weighted)
        if key not in trained:
            cfg = RNConfig(epochs=args.rn_epochs, seed=init_seed)
            model, _ = train_rn(d["x"][d["train"]], d["plan"][d["train"]], cfg, d["x"][d["val"]], d["plan"][d["val"]],
                                progress=False, w_train=d["weights"][d["train"]] if weighted else None)
            trained[key] = save_rn(model, cfg, FEATURE_LAYOUT, args.out / f"rn-{args.task}-{name}.pt")
        return trained[key]

    paths = {"prior": prior_in[3] or trained_here(p, "prior", args.seed),
             "prior, another init seed": trained_here(p, "prior-reseeded", args.seed + 1),
             "adaptive, weighted": adapt_in[3] or trained_here(a, "adaptive-weighted", args.seed, weighted=True),
             "adaptive, raw": trained_here(a, "adaptive-raw", args.seed)}
    pointnets = {"prior": prior_in[2], "prior, another init seed": prior_in[2], "adaptive, weighted": adapt_in[2],
                 "adaptive, raw": adapt_in[2]}
    own_val = {"adaptive, weighted": a, "adaptive, raw": a}  # the RNs scored on their own held-out demos too
    for second, (_, s) in seconds.items():
        paths[second] = trained_here(data[second], f"second-prior-seed{s}", args.seed)
        pointnets[second] = prior_in[2]
        own_val[second] = data[second]
    models = {name: load_rn(path) for name, path in paths.items()}
    common = p["x"][p["val"]]
    probs = {name: predict_proba(m, common) for name, m in models.items()}
    own = {name: (predict_proba(m, own_val[name]["x"][own_val[name]["val"]]),
                  a["weights"][a["val"]] if name == "adaptive, weighted" else None)
           if name in own_val else (probs[name], None) for name, m in models.items()}
    seeds = eval_scene_seeds(args.seed, args.scenes)
    outcomes = {name: rn_outcomes(paths[name], pointnets[name], args.task, seeds, defaults.n_points,
                                  defaults.episode_frames, 1.0, ("rn",))["rn"] for name in models}
    wins = {name: (sum(o.success for o in out), len(out)) for name, out in outcomes.items()}

    dims = ", ".join(plb.dim_names)
    second_lines = [f"- another prior run `{directory}` (seed {s}): {len(data[second]['x'])} demos, "
                    f"{len(data[second]['val'])} held out" for second, (directory, s) in seconds.items()]
    lines = [(f"RN from prior-only demos against RN from adaptive-proposal demos, task `{args.task}` "
             f"(`python -m experiments.proposal_rn`)."), "",
             f"- prior run `{args.prior_dir}`: {len(p['x'])} demos, {len(p['val'])} held out",
             (f"- adaptive run `{args.adaptive_dir}` (seed {adaptive_seed}): {len(a['x'])} demos, {len(a['val'])} "
             f"held out, effective sample size of their weights {effective_sample_size(a['weights']):.0f}, largest "
             f"weight {a['weights'].max() / a['weights'].mean():.1f}x the mean"),
             *second_lines,
             "",
             (f"| RN | largest Fig 7 bar difference from the prior RN per dimension ({dims}), common inputs | "
             f"the same, each run's own held-out demos | argmax plan on {args.scenes} unseen scenes (95% CI) |"),
             "|---|---|---|---|"]
    for name in models:
        gap = bar_gaps(probs[name], probs["prior"])
        gap_own = bar_gaps(own[name][0], own["prior"][0], own[name][1])
        overlap = "" if name == "prior" else (" (overlaps the prior RN's)" if intervals_overlap(wins[name], wins["prior"])
                                              else " (does not overlap the prior RN's)")
        lines.append(f"| {name} | {' '.join(f'{g:.2f}' for g in gap)} (max {max(gap):.2f}) | "
                     f"{' '.join(f'{g:.2f}' for g in gap_own)} (max {max(gap_own):.2f}) | "
                     f"{format_rate(*wins[name])}{overlap} |")
    if args.init_seeds > 1:
        k = args.init_seeds
        # name -> (file stem of its RNs, demos, trained with their weights, init seeds)
        sides = {"prior": ("prior-raw", p, False, range(k)),
                 "prior, the other K seeds (the floor)": ("prior-raw", p, False, range(k, 2 * k)),
                 "adaptive, weighted": ("adaptive-w", a, True, range(k)),
                 "adaptive, raw": ("adaptive-raw", a, False, range(k))}
        for second, (_, s) in seconds.items():
            sides[second] = (f"second-prior-seed{s}-raw", data[second], False, range(k))
        each = {name: [predict_proba(load_rn(trained_here(d, f"{stem}-init{s}", s, w)), common) for s in seeds]
                for name, (stem, d, w, seeds) in sides.items()}
        means = {name: mean_probs(runs) for name, runs in each.items()}
        train = a["train"]
        means["adaptive, raw, label-shift corrected (not in the pipeline)"] = mean_probs(
            [label_shift(probs, a["plan"][train], a["weights"][train]) for probs in each["adaptive, raw"]])
        lines += ["", (f"Fig 7 averaged over {k} RNs per side, each trained here from its own initialisation (seeds "
                       f"0..{k - 1}; the floor's {k}..{2 * k - 1}), on the common inputs:"), "",
                  f"| mean of {k} RNs | largest bar difference from the prior RNs' mean per dimension ({dims}) |",
                  "|---|---|"]
        for name in list(means)[1:]:
            gap = bar_gaps(means[name], means["prior"])
            lines.append(f"| {name} | {' '.join(f'{g:.2f}' for g in gap)} (max {max(gap):.2f}) |")
        if seconds:
            lines += ["", *pairwise_gaps(means, {f"prior (seed {args.seed})": "prior",
                                                **{f"prior (seed {s})": n for n, (_, s) in seconds.items()}},
                                         "adaptive, weighted", k)]
    fig_path = (args.markdown.with_name(f"{args.markdown.stem}_fig7.png") if args.markdown
                else args.out / "proposal_rn_fig7.png")
    plot_rn_probabilities({f"{args.task}: {name}": pr for name, pr in probs.items()}, plb.dim_names,
                          [d.choices for d in plb.dims], fig_path)
    lines += ["", f"![Fig 7 of the RNs on the common inputs]({fig_path.name})" if args.markdown else
              f"Fig 7 of the RNs on the common inputs: `{fig_path}`."]
    report = "\n".join(lines) + "\n"
    print(report)
    if args.markdown:
        args.markdown.write_text(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
