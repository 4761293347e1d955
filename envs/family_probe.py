"""Try other ranges for one family of a mixed variant (issue #26's design loop): given plans on scenes drawn from the
changed family only, so that a family can be tuned until the plans meant for it succeed and the others fail.

``python -m envs.family_probe --task tweeze_mixed --family 1 --set cube_size=0.029,0.032 --set tip_gap=0.056,0.06
--plans 0,0,4,2,6,1 2,2,5,3,6,1 --scenes 15 --first-seed 32000`` prints each plan's successes on the scenes of seeds
32000-32014, every one drawn from family 1 with those two ranges changed (the variant's family record with
``dataclasses.replace``: a field it does not have, or a range its checks refuse, is a clear error).

For the length of the probe the variant's class draws every scene from the changed family (its ``families`` table
is swapped in this process and restored after, also on an error); nothing is written, the task module is
untouched, and ``scene_params["family"]`` then says only which slot of the table was drawn. A probe is a design
aid, not a measurement of the variant: once a range is chosen, edit the task module and measure it with
``python -m envs.families``.

``--prior N`` asks the question the RN's target turns on before any demos are made: N plans sampled from the task's
prior on the changed family's scenes (plan i on scene i mod --scenes), and from the successful ones, as
``envs.families.family_decodings`` does with demos, the plan each RN decoding would execute if the RN read the family
perfectly (the successes' per-dimension shares; the library is the distinct successful plans); those plans then run
on the probe's scenes. A family whose decoded plans fail there cannot be solved by the paper's decoding reading the
family alone, however many demos are made (docs/guide/tasks.md, hammer_mixed).

Each plan's line also gives its mean reward (the task's measure, what the LN's A2C is paid) on the probe's scenes,
and the probe names the *reward traps*: plans that earn a higher mean reward than the most successful plan tried
while succeeding less often. A2C paid that reward drifts towards them after its pre-training (docs/guide/tasks.md,
unscrew_mixed: the flasks' spun caps), so a family without traps among the plans an RL agent finds is the safer
design.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np

from prl.plb import load_plb, parse_plan, validate_plan
from prl.stats import format_rate

Range = tuple[float, float]


@dataclasses.dataclass(frozen=True)
class PlanRecord:
    """One plan's result on a probe's scenes."""

    plan: tuple[int, ...]
    successes: int
    scenes: int
    mean_reward: float
    """The task's measure (the LN's reward) averaged over the scenes, successes and failures alike."""

    @property
    def rate(self) -> float:
        return self.successes / self.scenes if self.scenes else 0.0


def plan_record(plan: Sequence[int], outcomes: Sequence[Any]) -> PlanRecord:
    """The record of ``plan`` from its outcomes (``envs.trials.TrialOutcome``: ``success``, ``measure``)."""
    rewards = [float(o.measure) for o in outcomes]
    return PlanRecord(tuple(int(v) for v in plan), sum(bool(o.success) for o in outcomes), len(outcomes),
                      float(np.mean(rewards)) if rewards else 0.0)


def most_successful(records: Sequence[PlanRecord]) -> PlanRecord:
    """The record with the highest success rate, ties to the higher mean reward (then the first given)."""
    return max(records, key=lambda r: (r.rate, r.mean_reward))


def reward_traps(records: Sequence[PlanRecord]) -> list[PlanRecord]:
    """The plans that an agent paid by the mean reward would prefer to the most successful plan
    (``most_successful``): a higher mean reward and a lower success rate. In the order given."""
    if not records:
        return []
    best = most_successful(records)
    return [r for r in records if r.rate < best.rate and r.mean_reward > best.mean_reward]


def parse_setting(text: str) -> tuple[str, Range]:
    """``"field=low,high"`` -> ``(field, (low, high))``; ValueError naming the text when it is not of that form."""
    name, sep, values = text.partition("=")
    parts = values.split(",")
    try:
        low, high = (float(v) for v in parts) if len(parts) == 2 else (None, None)
    except ValueError:
        low = high = None
    if not sep or not name.strip().isidentifier() or low is None or high is None:
        raise ValueError(f"--set {text!r}: expected field=low,high (e.g. cube_size=0.029,0.032)")
    return name.strip(), (low, high)


def changed_family(spec: Any, changes: Mapping[str, Range]) -> Any:
    """A copy of the family record ``spec`` with ``changes``; ValueError naming a field it does not have (its
    own checks name a bad range)."""
    fields = {f.name for f in dataclasses.fields(spec)}
    unknown = sorted(set(changes) - fields)
    if unknown:
        raise ValueError(f"family {spec.name!r} has no field {unknown[0]!r}; its fields: {', '.join(sorted(fields))}")
    return dataclasses.replace(spec, **changes)


@contextmanager
def family_ranges(cls: Any, family: int, changes: Mapping[str, Range]) -> Iterator[Any]:
    """While open, every scene of the mixed variant ``cls`` is drawn from family ``family`` with ``changes``
    (yielded); the class's own table is put back on exit. ValueError naming a family index out of range."""
    table = tuple(cls.families)
    if not 0 <= family < len(table):
        raise ValueError(f"{cls.__name__} has families 0..{len(table) - 1}, not {family}")
    spec = changed_family(table[family], changes)
    cls.families = (spec,) * len(table)
    try:
        yield spec
    finally:
        cls.families = table


def mixed_class(task: str) -> Any:
    """The environment class of the mixed variant ``task``; ValueError naming a task without scene families."""
    from envs.families import family_plans  # heavy: loads the simulator
    from envs.tasks import task_class

    if family_plans(task) is None:
        raise ValueError(f"task {task!r} has no scene families (no family_expert_plans)")
    return task_class(task)


def probe(task: str, family: int, changes: Mapping[str, Range], plans: Sequence[Sequence[int]],
          seeds: Sequence[int]) -> dict[tuple[int, ...], list[Any]]:
    """Each plan's outcomes (``envs.trials.TrialOutcome``) on ``seeds``' scenes, all drawn from the changed
    family. ValueError for a task without families or a bad plan (``prl.plb``)."""
    from envs.trials import run_trials  # heavy: loads the simulator

    cls = mixed_class(task)
    checked = [tuple(int(v) for v in validate_plan(p)) for p in plans]
    with family_ranges(cls, family, changes):
        return {plan: run_trials(task, [plan] * len(seeds), list(seeds)) for plan in checked}


def prior_decodings(task: str, family: int, changes: Mapping[str, Range], seeds: Sequence[int], n_prior: int,
                    rng_seed: int) -> tuple[int, dict[str, tuple[int, ...]]]:
    """(successes, {decoding: plan}) of ``n_prior`` prior-sampled plans on the changed family's scenes (plan i on
    ``seeds[i % len(seeds)]``, plans drawn with ``numpy.random.default_rng(rng_seed)``): the plans
    ``envs.families.family_decodings`` gives for the successful ones (equal weights: they were drawn from the prior).
    ValueError when none succeeds (nothing to decode)."""
    from envs.families import family_decodings  # heavy: loads the simulator
    from envs.trials import run_trials

    if n_prior < 1 or not seeds:
        raise ValueError(f"--prior needs at least one plan and one scene, got {n_prior} plans, {len(seeds)} scenes")
    cls = mixed_class(task)
    plb = load_plb()
    rng = np.random.default_rng(rng_seed)
    plans = [tuple(int(v) for v in plb.sample_plan(task, rng)) for _ in range(n_prior)]
    with family_ranges(cls, family, changes):
        outcomes = run_trials(task, plans, [seeds[i % len(seeds)] for i in range(n_prior)])
    won = [p for p, o in zip(plans, outcomes) if o.success]
    if not won:
        raise ValueError(f"none of the {n_prior} prior-sampled plans succeeded on family {family}: nothing to decode")
    decoded = family_decodings(won, [family] * len(won), np.ones(len(won)), plb.prior(task))[family]
    return len(won), decoded


def main(argv: list[str] | None = None) -> int:
    summary = " ".join(__doc__.split("\n\n")[0].split())
    parser = argparse.ArgumentParser(prog="python -m envs.family_probe", description=summary)
    parser.add_argument("--task", required=True, help="a mixed variant, e.g. tweeze_mixed")
    parser.add_argument("--family", type=int, required=True, help="the family whose ranges change (0, 1, ...)")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=LOW,HIGH",
                        help="a range of the family record to change (repeatable)")
    parser.add_argument("--plans", nargs="+", default=[], metavar="A0,A1,A2,A3,A4,A5",
                        help="the plans to try, each as six comma-separated indices")
    parser.add_argument("--prior", type=int, default=0, metavar="N",
                        help="also sample N plans from the task's prior on the family's scenes and try the plan each "
                             "RN decoding would take from their successes (see above)")
    parser.add_argument("--scenes", type=int, default=20, help="scenes per plan")
    parser.add_argument("--first-seed", type=int, default=30000,
                        help="scene seeds first-seed .. first-seed + scenes - 1 (keep clear of the trial and "
                             "evaluation seeds)")
    args = parser.parse_args(argv)
    if args.scenes < 1:
        parser.error(f"--scenes must be >= 1, got {args.scenes}")
    if args.prior < 0 or (not args.plans and not args.prior):
        parser.error(f"give --plans, or --prior N with N >= 1 (got --prior {args.prior})")
    try:
        changes = dict(parse_setting(s) for s in args.set)
        plans = [tuple(int(v) for v in parse_plan(p)) for p in args.plans]
    except ValueError as exc:
        parser.error(str(exc))
    seeds = list(range(args.first_seed, args.first_seed + args.scenes))
    decoded: dict[str, tuple[int, ...]] = {}
    try:
        if args.prior:
            won, decoded = prior_decodings(args.task, args.family, changes, seeds, args.prior, args.first_seed)
            plans += [p for p in decoded.values() if p not in plans]
        out = probe(args.task, args.family, changes, plans, seeds)
    except (ValueError, TypeError) as exc:
        parser.error(str(exc))
    what = ", ".join(f"{k} {lo:g}-{hi:g}" for k, (lo, hi) in changes.items()) or "unchanged"
    print(f"{args.task} family {args.family} ({what}), scene seeds {seeds[0]}-{seeds[-1]}:")
    if args.prior:
        print(f"  prior-sampled plans: {format_rate(won, args.prior)} succeeded")
    records = [plan_record(plan, outcomes) for plan, outcomes in out.items()]
    for rec in records:
        names = [k for k, v in decoded.items() if v == rec.plan]
        tag = f"  ({', '.join(names)} of the prior's successes)" if names else ""
        print(f"  {list(rec.plan)}  {format_rate(rec.successes, rec.scenes)}  mean reward {rec.mean_reward:.3g}{tag}")
    traps = reward_traps(records)
    if traps:
        best = most_successful(records)
        print(f"  reward traps (a higher mean reward than {list(best.plan)}'s {best.mean_reward:.3g} with fewer "
              f"successes; A2C paid this reward drifts towards them):")
        for rec in traps:
            print(f"    {list(rec.plan)}  mean reward {rec.mean_reward:.3g}, {rec.successes}/{rec.scenes}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
