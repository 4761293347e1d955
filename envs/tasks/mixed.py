"""Shared part of the mixed task variants (issue #26): each scene is drawn, from its seed, from one of several
*families* of the same task whose physics needs different plans.

A mixed variant subclasses its base task and this mixin (``class PRLUnscrewMixedEnv(MixedFamilies,
PRLUnscrewEnv)``) and declares:

- ``families``: one entry per family (what the variant draws a scene of that family from), at least two;
- ``family_expert_plans``: family index -> a hand-written plan that opens / drives / ... that family's scenes;
- ``expert_plan``: family 0's plan (the one plan the rest of the pipeline calls the task's expert).

The scene's family is the first value the variant draws from the episode's seeded generator
(``draw_family``), so the same seed gives the same family and the same scene; it is kept as
``scene_params["family"]`` (an int). Nothing in the executor, the RN or the LN reads it: x tells the families
apart through what they change (sizes in the meshes rebuilt from ``scene_params``, poses in x_manip).
A bad configuration (no families, a plan missing for one, a malformed plan, an index out of range) is a
``ValueError`` naming the bad value, raised when the environment is created.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np

from prl.plb import load_plb


class MixedFamilies:
    """Mixin of a mixed task variant: the family table, its checks and the seeded family draw."""

    families: ClassVar[Sequence[Any]] = ()
    """One entry per family (the variant's own description of a family's ranges); at least two."""
    family_expert_plans: ClassVar[Mapping[int, tuple[int, ...]]] = {}
    """Family index (0, 1, ...) -> the hand-written plan of that family (a reference, not a label)."""
    expert_plan: tuple[int, ...] = ()

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        type(self).check_families()
        super().__init__(*args, **kwargs)

    @classmethod
    def check_families(cls) -> None:
        """``ValueError`` naming the bad value unless ``families`` has at least two entries,
        ``family_expert_plans`` maps exactly the indices 0 .. len(families) - 1 to valid plans (``prl.plb``), no two
        the same, and ``expert_plan`` is family 0's plan."""
        name = cls.__name__
        families = cls.families
        if isinstance(families, (str, bytes)) or not isinstance(families, Sequence) or len(families) < 2:
            raise ValueError(f"{name}.families must list at least two families, got {families!r}")
        plans = cls.family_expert_plans
        if not isinstance(plans, Mapping) or not plans:
            raise ValueError(f"{name}.family_expert_plans must map each family index to a plan, got {plans!r}")
        wanted = set(range(len(families)))
        bad_keys = [k for k in plans if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k not in wanted]
        if bad_keys:
            raise ValueError(f"{name}.family_expert_plans has family index {bad_keys[0]!r}, not one of the "
                             f"{len(families)} families 0..{len(families) - 1}")
        missing = sorted(wanted - {int(k) for k in plans})
        if missing:
            raise ValueError(f"{name}.family_expert_plans has no plan for family {missing[0]} "
                             f"(families 0..{len(families) - 1})")
        plb = load_plb()
        for family, plan in plans.items():
            try:
                plb.validate_plan(plan)
            except ValueError as exc:
                raise ValueError(f"{name}.family_expert_plans[{family}] = {plan!r} is not a plan: {exc}") from None
        seen: dict[tuple[int, ...], int] = {}
        for family in sorted(plans):
            plan = tuple(int(v) for v in plans[family])
            if plan in seen:
                raise ValueError(f"{name}.family_expert_plans: families {seen[plan]} and {family} have the same plan "
                                 f"{plan!r}; families that one plan solves are one family")
            seen[plan] = family
        if tuple(cls.expert_plan) != tuple(plans[0]):
            raise ValueError(f"{name}.expert_plan {tuple(cls.expert_plan)!r} must be family 0's plan "
                             f"{tuple(plans[0])!r}")

    @classmethod
    def family_spec(cls, family: Any) -> Any:
        """The ``families`` entry of ``family``; ``ValueError`` naming an index out of range."""
        n = len(cls.families)
        if isinstance(family, bool) or not isinstance(family, (int, np.integer)) or not 0 <= family < n:
            raise ValueError(f"family {family!r} is out of range: {cls.__name__} has families 0..{n - 1}")
        return cls.families[int(family)]

    @classmethod
    def family_plan(cls, family: Any) -> tuple[int, ...]:
        """The hand-written plan of ``family``; ``ValueError`` naming an index out of range."""
        cls.family_spec(family)
        return tuple(int(v) for v in cls.family_expert_plans[int(family)])

    def draw_family(self, rng: np.random.RandomState) -> int:
        """The scene's family: a uniform draw from ``rng`` (the episode's seeded generator), made first, before
        the family's own values."""
        return int(rng.randint(len(self.families)))
