"""The search every mixed variant must survive: does one fixed plan do the variant's job?

A mixed variant (``envs/tasks/<task>_mixed.py``) draws each scene from families that need different plans, so that
a learner must read the scene. Checking that against the families' own experts is not enough: a plan nobody wrote
may open both families. Per variant, this searches fixed plans with the cross-entropy method (``prl.cem``) twice,
from the variant's PLB prior mixed half and half with the uniform distribution and from the uniform one: each
round draws ``per_round`` plans and runs each on ``scenes_per_plan`` fresh scenes, scores a plan by its success
rate (then its mean measure) and moves the categoricals towards the top quarter, with a floor at 0.1 of the start.
Then the ``top`` best plans of each search, and every family's expert, run on a fixed set of ``check_scenes``
scenes no search saw, as many of each family (``balanced_check_seeds``: the first seeds of a fixed sequence whose
scene is of a family not yet full, each scene's family read after its reset as a reference may, never by a plan;
the same set on every run, recorded in the JSON). The variant draws its families with equal probability, so a
balanced set measures a plan's rate on the variant without the noise of the families' mix in 50 draws.

The variant holds when the best fixed plan on the check scenes succeeds on at most ``BEST_FIXED_TARGET`` of them,
each family's expert on at least ``FAMILY_TARGET`` of its own family's, and the family oracle (each scene's own
family's expert) on at least ``FAMILY_TARGET`` of all.

    python -m envs.variant_search --tasks hammer_mixed,sweep_mixed,unscrew_mixed,tweeze_mixed \\
        --json docs/variant_search.json --out docs/variant_search.md

writes the record and the page; ``--from-json`` makes the page again from the committed record alone. A task is
searched and recorded as it finishes, and a task already in ``--json`` with the same settings is kept, so an
interrupted run resumes.

Each record keeps the code it ran on (``prl.version.trial_version``: the task's modules, its PLB entry, the
executor). A record of other code is stale: the page says so, and the next run searches that variant again, with
every plan the stale record had found (or carried) added to the check scenes ("earlier search"), so that a
redesign must refuse the loopholes found before it as well as those its own search finds. A record made before
codes were recorded has none and is kept.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from prl import cem
from prl.atomic import write_atomic
from prl.constants import REPO_ROOT
from prl.plb import load_plb
from prl.stats import wilson_interval
from prl.version import trial_version

BEST_FIXED_TARGET = 0.6
"""A variant holds when no fixed plan succeeds on more than this share of its check scenes."""
FAMILY_TARGET = 0.9
"""... while each family's expert succeeds on at least this share of its family's scenes, and the oracle of all."""
CHECK_DESIGN = "balanced"
"""How the check scenes are chosen (``balanced_check_seeds``): a record made otherwise has its checks run again."""
SEARCH_RECORD = REPO_ROOT / "docs" / "variant_search.json"
"""The committed record of every variant's search."""
STARTS: tuple[str, ...] = ("prior+uniform", "uniform")
"""Where a search starts: the variant's prior mixed half and half with uniform, or uniform."""


@dataclass(frozen=True)
class SearchSettings:
    """How hard one variant is searched."""

    rounds: int = 4
    """CEM rounds per start."""
    per_round: int = 20
    """Plans drawn per round."""
    scenes_per_plan: int = 3
    """Fresh scenes each drawn plan runs on."""
    top: int = 5
    """Best distinct plans of each search re-run on the check scenes."""
    check_scenes: int = 50
    """The fixed unseen scenes the best plans, the family experts and the oracle are measured on."""
    seed: int = 0
    """Seed of the searches' plan draws (the scenes' seeds are hashes, ``search_seed``)."""

    def __post_init__(self) -> None:
        for name in ("rounds", "per_round", "scenes_per_plan", "top", "check_scenes"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")


def search_seed(task: str, stage: str, i: int) -> int:
    """A scene seed of this search (a hash: it meets the trial, evaluation, red-team and LN seeds only by chance)."""
    return zlib.crc32(f"variant-search/{task}/{stage}/{i}".encode())


def check_seeds(task: str, n: int) -> list[int]:
    """The first ``n`` seeds of ``task``'s fixed sequence of check scenes."""
    return [search_seed(task, "check", i) for i in range(n)]


def balanced_check_seeds(task: str, n: int, n_families: int, family_of: Callable[[list[int]], list[int]],
                         limit: int = 20) -> tuple[list[int], list[int]]:
    """The first seeds of ``check_seeds``' sequence that fill ``n // n_families`` scenes of each family (``n``
    rounded down to a multiple of ``n_families``), in sequence order, and each one's family; ``family_of(seeds)``
    reads each scene's family. ValueError when ``limit * n`` seeds do not fill every family."""
    per, seeds, families, counts = n // n_families, [], [], [0] * n_families
    candidates = check_seeds(task, limit * n)
    for start in range(0, len(candidates), n):
        block = candidates[start:start + n]
        for seed, family in zip(block, family_of(block), strict=True):
            if 0 <= family < n_families and counts[family] < per:
                counts[family] += 1
                seeds.append(seed)
                families.append(family)
        if min(counts) == per:
            return seeds, families
    raise ValueError(f"{task}: {limit * n} check seeds gave families {counts}, not {per} of each")


def start_probs(prior: Sequence[np.ndarray], start: str) -> list[np.ndarray]:
    """The categoricals a search starts from (``STARTS``); ValueError naming an unknown start."""
    flat = cem.uniform([len(p) for p in prior])
    if start == "uniform":
        return flat
    if start == "prior+uniform":
        return [0.5 * np.asarray(p, float) / np.sum(p) + 0.5 * u for p, u in zip(prior, flat, strict=True)]
    raise ValueError(f"unknown search start {start!r}; known: {', '.join(STARTS)}")


Runner = Callable[[str, list[list[int]], list[int]], list[Any]]
"""``run(task, plans, seeds)`` -> one outcome (``success``, ``measure``) per plan and scene: ``envs.trials.run_trials``."""


def cem_search(task: str, start: str, prior: Sequence[np.ndarray], settings: SearchSettings,
               run: Runner) -> dict[str, Any]:
    """One cross-entropy search of fixed plans on ``task`` from ``start`` (module docstring): each round's success
    rate, and every plan tried with its successes and scenes, pooled over the rounds."""
    reference = start_probs(prior, start)
    probs = reference
    rng = np.random.default_rng(zlib.crc32(f"variant-search/{task}/{settings.seed}/{start}".encode()))
    tried: dict[tuple[int, ...], list[int]] = {}
    rates = []
    n = settings.scenes_per_plan
    for r in range(settings.rounds):
        plans = cem.sample(probs, settings.per_round, rng)
        seeds = [search_seed(task, f"{start}/s{settings.seed}/r{r}", i) for i in range(len(plans) * n)]
        outcomes = run(task, [list(map(int, plan)) for plan in plans for _ in range(n)], seeds)
        scores = []
        for k, plan in enumerate(plans):
            mine = outcomes[k * n:(k + 1) * n]
            wins = sum(bool(o.success) for o in mine)
            row = tried.setdefault(tuple(int(v) for v in plan), [0, 0])
            row[0] += wins
            row[1] += n
            scores.append(1000.0 * wins / n + float(np.mean([o.measure for o in mine])))
        rates.append(float(np.mean([bool(o.success) for o in outcomes])))
        probs = cem.update(probs, cem.elites(plans, np.array(scores), 0.25), smoothing=0.7, reference=reference,
                           floor=0.1)
        print(f"{task} from {start}, round {r}: {sum(bool(o.success) for o in outcomes)}/{len(outcomes)}", flush=True)
    return {"start": start, "round_rates": rates,
            "tried": [{"plan": list(p), "successes": k, "scenes": m} for p, (k, m) in tried.items()]}


def best_tried(search: dict[str, Any], top: int) -> list[tuple[int, ...]]:
    """The ``top`` best distinct plans a search tried: by success rate, then by scenes tried (more evidence)."""
    ranked = sorted(search["tried"], key=lambda t: (-t["successes"] / t["scenes"], -t["scenes"]))
    return [tuple(t["plan"]) for t in ranked[:top] if t["successes"] > 0]


def check(task: str, plans: Sequence[tuple[int, ...]], seeds: Sequence[int], run: Runner
          ) -> dict[tuple[int, ...], list[bool]]:
    """Each of ``plans`` (distinct) on every check scene: ``{plan: success per scene}``."""
    return {plan: [bool(o.success) for o in run(task, [list(plan)] * len(seeds), list(seeds))]
            for plan in dict.fromkeys(plans)}


def verdict(record: dict[str, Any]) -> dict[str, Any]:
    """The targets read from one variant's record: the best fixed plan's rate, each family expert's rate on its own
    family, the oracle's rate, and whether the variant holds."""
    fams = record["families"]
    n = len(fams)
    rates = {tuple(c["plan"]): sum(c["successes"]) / n for c in record["checked"]}
    best_plan, best = max(rates.items(), key=lambda kv: kv[1])
    experts = {int(k): tuple(p) for k, p in record["family_experts"].items()}
    own = {}
    for k, plan in experts.items():
        wins = [s for s, f in zip(_successes(record, plan), fams, strict=True) if f == k]
        own[k] = (sum(wins), len(wins))
    oracle = [_successes(record, experts[f])[i] if f in experts else False for i, f in enumerate(fams)]
    holds = (best <= BEST_FIXED_TARGET and all(n_f and k / n_f >= FAMILY_TARGET for k, n_f in own.values())
             and sum(oracle) / n >= FAMILY_TARGET)
    return {"best_plan": list(best_plan), "best": best, "best_n": n, "own": own, "oracle": sum(oracle), "holds": holds}


def best_fixed_plan(task: str, path: Path = SEARCH_RECORD) -> list[int] | None:
    """The best fixed plan the search found on ``task`` by its record at ``path`` (``verdict``), or None when the
    record has no search of it. The simulator is not loaded."""
    records = json.loads(Path(path).read_text()) if Path(path).is_file() else []
    return next((verdict(r)["best_plan"] for r in records if r["task"] == task), None)


def _successes(record: dict[str, Any], plan: tuple[int, ...]) -> list[bool]:
    return next(c["successes"] for c in record["checked"] if tuple(c["plan"]) == tuple(plan))


def search_variant(task: str, settings: SearchSettings, run: Runner,
                   family_experts: dict[int, tuple[int, ...]], family_of: Callable[[list[int]], list[int]],
                   prior: Sequence[np.ndarray] | None = None,
                   searches: list[dict[str, Any]] | None = None, carried: Sequence[tuple[int, ...]] = (),
                   code: str | None = None) -> dict[str, Any]:
    """Both searches on ``task`` (from ``prior``, by default the task's PLB prior; ``searches`` reuses finished
    ones), then the best plans, the plans ``carried`` from earlier records (``earlier_plans``) and the family experts
    on the balanced check scenes: the record, with ``code`` (``prl.version.trial_version``) when given."""
    prior = load_plb().prior(task) if prior is None else prior
    searches = searches or [cem_search(task, start, prior, settings, run) for start in STARTS]
    found = [plan for s in searches for plan in best_tried(s, settings.top)]
    carried = [tuple(int(v) for v in p) for p in carried]
    seeds, families = balanced_check_seeds(task, settings.check_scenes, len(family_experts), family_of)
    checked = check(task, [*family_experts.values(), *found, *carried], seeds, run)
    record = {"task": task, "settings": dataclasses.asdict(settings), "check": CHECK_DESIGN, "searches": searches,
              "check_seeds": seeds, "families": families,
              "family_experts": {str(k): list(p) for k, p in family_experts.items()},
              "checked": [{"plan": list(p), "found": p in found, "carried": p in carried and p not in found,
                           "successes": s} for p, s in checked.items()]}
    return record if code is None else {**record, "code": code}


def earlier_plans(records: Sequence[dict[str, Any]], task: str, code: str) -> list[tuple[int, ...]]:
    """The plans that ``task``'s records of code other than ``code`` found or carried (``search_variant``), in their
    order, each once: what a new search of a redesigned variant checks again. A record without a code is not
    of other code (it predates the codes)."""
    plans = [tuple(c["plan"]) for r in records if r["task"] == task and r.get("code", code) != code
             for c in r["checked"] if c.get("found") or c.get("carried")]
    return list(dict.fromkeys(plans))


def render(records: Sequence[dict[str, Any]], command: str, codes: dict[str, str] | None = None) -> str:
    """The page: per variant the targets, then every checked plan's rate overall and per family. ``codes``: each
    task's code today (``prl.version.trial_version``); a record of another code is marked stale."""
    codes = codes or {}
    plb = load_plb()
    lines = [f"<!-- Generated by `{command}` from docs/variant_search.json; do not edit by hand. -->",
             "# Mixed variants under search", "",
             ("Does one fixed plan do a mixed variant's job? Two cross-entropy searches over fixed plans per variant "
              "(from its prior mixed half and half with uniform, and from uniform; `envs/variant_search.py`), then "
              "the best plans they found and each family's expert on a fixed set of check scenes no search saw. A "
              f"variant holds when the best fixed plan succeeds on at most {BEST_FIXED_TARGET:.0%} of them, each "
              f"family's expert on at least {FAMILY_TARGET:.0%} of its own family's and the family oracle on at "
              f"least {FAMILY_TARGET:.0%} of all. A record searched on other code than today's "
              "(`prl.version.trial_version`: the task's modules, its PLB entry, the executor) is marked stale; the "
              "next search of that variant also checks every plan the stale record found (\"earlier search\")."), "",
             ("| variant | best fixed plan (check scenes, 95% CI) | family experts on their own family | oracle | "
              "holds |"), "|---|---|---|---|---|"]
    for rec in records:
        v, n = verdict(rec), len(rec["families"])
        lo, hi = wilson_interval(round(v["best"] * n), n)
        own = ", ".join(f"family {k}: {s}/{m}" for k, (s, m) in sorted(v["own"].items()))
        holds = "yes" if v["holds"] else "**no**"
        if "code" in rec and rec["task"] in codes and rec["code"] != codes[rec["task"]]:
            holds += f" (stale: searched on code `{rec['code']}`, today `{codes[rec['task']]}`)"
        lines.append(f"| {rec['task']} | `{v['best_plan']}`: {round(v['best'] * n)}/{n} = {v['best']:.2f} "
                     f"({lo:.2f}-{hi:.2f}) | {own} | {v['oracle']}/{n} | {holds} |")
    for rec in records:
        fams = rec["families"]
        s = rec["settings"]
        lines += ["", f"## {rec['task']}", "",
                  (f"{s['rounds']} rounds of {s['per_round']} plans x {s['scenes_per_plan']} scenes per start; "
                   + "; ".join(f"from {x['start']}: round success "
                               + ", ".join(f"{r:.2f}" for r in x["round_rates"]) for x in rec["searches"])
                   + f". Check scenes: {len(fams)} ("
                   + ", ".join(f"family {f}: {fams.count(f)}" for f in sorted(set(fams))) + ")."), "",
                  "| plan | choices | from | check scenes | per family |", "|---|---|---|---|---|"]
        experts = {tuple(p): k for k, p in rec["family_experts"].items()}
        for c in sorted(rec["checked"], key=lambda c: -sum(c["successes"])):
            plan = tuple(c["plan"])
            who = (f"family {experts[plan]} expert" if plan in experts
                   else "earlier search" if c.get("carried") else "search")
            per = ", ".join(f"{sum(w for w, g in zip(c['successes'], fams, strict=True) if g == f)}/{fams.count(f)}"
                            for f in sorted(set(fams)))
            names = ", ".join(str(x) for x in plb.decode(list(plan)))
            lines.append(f"| `{list(plan)}` | {names} | {who} | {sum(c['successes'])}/{len(fams)} | {per} |")
    return "\n".join(lines) + "\n"


def _families_of(task: str, seeds: list[int]) -> list[int]:
    """Each scene's family, read after its reset (as a reference may); -1 where the reset raised."""
    from envs.tasks import fast_resets, make_env  # heavy: loads the simulator

    env, out = make_env(task), []
    try:
        with fast_resets():
            for seed in seeds:
                try:
                    env.reset(seed=int(seed))
                    out.append(int(env.unwrapped.scene_params["family"]))
                except Exception:  # noqa: BLE001 - a scene that cannot be built is of no family
                    out.append(-1)
    finally:
        env.close()
    return out


def main(argv: list[str] | None = None) -> int:
    from envs.families import family_plans  # heavy: loads the simulator
    from envs.tasks import TASK_ENV_IDS
    from envs.trials import run_trials

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default="hammer_mixed,sweep_mixed,unscrew_mixed,tweeze_mixed")
    parser.add_argument("--json", type=Path, default=SEARCH_RECORD, help="the record (resumed)")
    parser.add_argument("--out", type=Path, default=Path("docs/variant_search.md"), help="the page")
    parser.add_argument("--from-json", action="store_true", help="only make the page from the record")
    for f in dataclasses.fields(SearchSettings):
        parser.add_argument(f"--{f.name.replace('_', '-')}", type=int, default=f.default)
    args = parser.parse_args(argv)
    command = "python -m envs.variant_search --from-json"
    records = json.loads(args.json.read_text()) if args.json.is_file() else []
    if not args.from_json:
        settings = SearchSettings(**{f.name: getattr(args, f.name) for f in dataclasses.fields(SearchSettings)})
        tasks = [t.strip() for t in args.tasks.split(",") if t.strip()]
        unknown = [t for t in tasks if t not in TASK_ENV_IDS]
        if unknown or not tasks:
            parser.error(f"unknown task(s) {unknown or '(none given)'}; known: {', '.join(TASK_ENV_IDS)}")
        plans = {task: family_plans(task) for task in tasks}  # every task checked before any search runs
        flat = [task for task, experts in plans.items() if experts is None]
        if flat:
            parser.error(f"task(s) {flat} have no scene families (family_expert_plans): not mixed variants")
        for task, experts in plans.items():
            code = trial_version(task)
            same = [r for r in records if r["task"] == task and r["settings"] == dataclasses.asdict(settings)
                    and r.get("code", code) == code]
            if same and same[0].get("check") == CHECK_DESIGN:
                continue
            rec = search_variant(task, settings, partial(run_trials, progress=False), experts,
                                 partial(_families_of, task), searches=same[0]["searches"] if same else None,
                                 carried=earlier_plans(records, task, code), code=code)
            records = [r for r in records if r["task"] != task] + [rec]
            write_atomic(args.json, json.dumps(records, indent=1) + "\n")
    if not records:
        parser.error(f"no record at {args.json}: run the search first")
    write_atomic(args.out, render(records, command, {r["task"]: trial_version(r["task"]) for r in records}))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
