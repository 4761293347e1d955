"""What every mixed task variant (issue #26, ``envs/tasks/<task>_mixed.py``) owes the rest of the project, checked on
each without building a scene: its registration, its family table (family 0's plan is the base task's expert) and
a bad table or family index named before any scene is built. Each variant's physics is tested in its own file."""

from __future__ import annotations

import pytest

from prl.task_registry import known_tasks

MIXED = tuple(t for t in known_tasks() if t.endswith("_mixed"))


def _cls(task: str):
    from envs.tasks import task_class  # heavy: loads the simulator's modules (no scene)

    return task_class(task)


def test_every_paper_task_has_a_mixed_variant() -> None:
    assert MIXED == ("hammer_mixed", "sweep_mixed", "tweeze_mixed", "unscrew_mixed")


@pytest.mark.parametrize("task", MIXED)
def test_the_interface_the_issue_asks_for(task: str) -> None:
    from envs.tasks import TASK_ENV_IDS

    cls, base = _cls(task), _cls(task.removesuffix("_mixed"))
    assert TASK_ENV_IDS[task] == f"PRL-{base.__name__.removeprefix('PRL').removesuffix('Env')}Mixed-v1"
    assert issubclass(cls, base) and cls.task_name == task
    assert cls.stages == base.stages and cls.unacted_dims == base.unacted_dims  # the base task's plan episode
    assert set(cls.family_expert_plans) == set(range(len(cls.families))) and len(cls.families) >= 2
    assert cls.expert_plan == cls.family_expert_plans[0]  # family 0's plan is the one the pipeline calls the expert
    if task != "tweeze_mixed":  # its family 0 holds a flat tile, not the base task's cube (envs/tasks/tweeze_mixed.py)
        assert cls.expert_plan == base.expert_plan  # family 0 is the base task's scenes: its plan is the base expert
    assert len(set(cls.family_expert_plans.values())) == len(cls.families)
    assert cls.family_plan(1) == cls.family_expert_plans[1]
    cls.check_families()


def _bad_tables(plans: dict[int, tuple[int, ...]], families: tuple) -> list[tuple[dict, str]]:
    """Bad family tables built from a variant's own, with the message each must raise."""
    p0, p1 = plans[0], plans[1]
    bad_plan = (*p1[:5], 9)
    return [
        ({"family_expert_plans": {}}, "family_expert_plans must map each family index to a plan, got {}"),
        ({"family_expert_plans": [p0, p1]}, "family_expert_plans must map"),
        ({"family_expert_plans": {0: p0}}, "no plan for family 1"),
        ({"family_expert_plans": {**plans, 2: p0}}, "family index 2, not one of the 2 families 0..1"),
        ({"family_expert_plans": {0: p0, "1": p1}}, "family index '1'"),
        ({"family_expert_plans": {0: p0, 1: bad_plan}},
         rf"family_expert_plans\[1\] = {_re(bad_plan)} is not a plan: .*tool_object_rot is 9"),
        ({"family_expert_plans": {0: p0, 1: p1[:3]}}, rf"family_expert_plans\[1\] = {_re(p1[:3])}"),
        ({"expert_plan": p1}, rf"expert_plan {_re(p1)} must be family 0's plan"),
        ({"families": ()}, r"families must list at least two families, got \(\)"),
        ({"families": families[:1]}, "families must list at least two families"),
        ({"family_expert_plans": {0: p0, 1: p0}}, rf"families 0 and 1 have the same plan {_re(p0)}"),
        ({"families": (families[0], "a family")},
         rf"BadMixed.families\[1\] must be a {type(families[0]).__name__}, got 'a family'"),
    ]


def _re(plan: tuple[int, ...]) -> str:
    return "\\(" + ", ".join(map(str, plan)) + "\\)"


@pytest.mark.parametrize("task", MIXED)
def test_a_bad_family_table_is_named_before_any_scene_is_built(task: str) -> None:
    cls = _cls(task)
    for attrs, match in _bad_tables(dict(cls.family_expert_plans), tuple(cls.families)):
        bad = type("BadMixed", (cls,), dict(attrs))  # not registered: only the class's checks run
        with pytest.raises(ValueError, match=match):
            bad.check_families()
        with pytest.raises(ValueError, match=match):
            bad()  # creating the environment checks the table first


@pytest.mark.parametrize("task", MIXED)
@pytest.mark.parametrize("family", [2, -1, 1.0, True, "0"])
def test_a_family_index_out_of_range_is_named(task: str, family) -> None:
    cls = _cls(task)
    with pytest.raises(ValueError, match=f"family {family!r} is out of range: {cls.__name__} has families 0..1"):
        cls.family_plan(family)
