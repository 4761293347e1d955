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
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

from prl.plb import parse_plan, validate_plan
from prl.stats import format_rate

Range = tuple[float, float]


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


def probe(task: str, family: int, changes: Mapping[str, Range], plans: Sequence[Sequence[int]],
          seeds: Sequence[int]) -> dict[tuple[int, ...], list[Any]]:
    """Each plan's outcomes (``envs.trials.TrialOutcome``) on ``seeds``' scenes, all drawn from the changed
    family. ValueError for a task without families or a bad plan (``prl.plb``)."""
    from envs.families import family_plans  # heavy: loads the simulator
    from envs.tasks import task_class
    from envs.trials import run_trials

    if family_plans(task) is None:
        raise ValueError(f"task {task!r} has no scene families (no family_expert_plans)")
    cls = task_class(task)
    checked = [tuple(int(v) for v in validate_plan(p)) for p in plans]
    with family_ranges(cls, family, changes):
        return {plan: run_trials(task, [plan] * len(seeds), list(seeds)) for plan in checked}


def main(argv: list[str] | None = None) -> int:
    summary = " ".join(__doc__.split("\n\n")[0].split())
    parser = argparse.ArgumentParser(prog="python -m envs.family_probe", description=summary)
    parser.add_argument("--task", required=True, help="a mixed variant, e.g. tweeze_mixed")
    parser.add_argument("--family", type=int, required=True, help="the family whose ranges change (0, 1, ...)")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=LOW,HIGH",
                        help="a range of the family record to change (repeatable)")
    parser.add_argument("--plans", nargs="+", required=True, metavar="A0,A1,A2,A3,A4,A5",
                        help="the plans to try, each as six comma-separated indices")
    parser.add_argument("--scenes", type=int, default=20, help="scenes per plan")
    parser.add_argument("--first-seed", type=int, default=30000,
                        help="scene seeds first-seed .. first-seed + scenes - 1 (keep clear of the trial and "
                             "evaluation seeds)")
    args = parser.parse_args(argv)
    if args.scenes < 1:
        parser.error(f"--scenes must be >= 1, got {args.scenes}")
    try:
        changes = dict(parse_setting(s) for s in args.set)
        plans = [tuple(int(v) for v in parse_plan(p)) for p in args.plans]
    except ValueError as exc:
        parser.error(str(exc))
    seeds = list(range(args.first_seed, args.first_seed + args.scenes))
    try:
        out = probe(args.task, args.family, changes, plans, seeds)
    except (ValueError, TypeError) as exc:
        parser.error(str(exc))
    what = ", ".join(f"{k} {lo:g}-{hi:g}" for k, (lo, hi) in changes.items()) or "unchanged"
    print(f"{args.task} family {args.family} ({what}), scene seeds {seeds[0]}-{seeds[-1]}:")
    for plan, outcomes in out.items():
        print(f"  {list(plan)}  {format_rate(sum(bool(o.success) for o in outcomes), len(outcomes))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
