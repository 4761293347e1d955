"""Shared checks of physical honesty (docs/guide/design.md "Honesty rules") for the task tests: the tool is a free body held by
contact only, and nothing writes a pose, velocity or joint state while a plan executes."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest


def assert_tool_held_by_contact_only(env: Any) -> None:
    """The tool is a free dynamic body (not kinematic, in no articulation, no extra component on it) and the
    scene holds no joint, drive or gear outside the articulations (no constraint between hand and tool)."""
    tool_body = env.tool._bodies[0]
    assert not tool_body.kinematic
    assert not hasattr(tool_body, "articulation")
    for link in env.scene.px.get_articulation_link_components():
        assert link.entity is not tool_body.entity
    names = {type(c).__name__ for c in tool_body.entity.components}
    assert names <= {"PhysxRigidDynamicComponent", "RenderBodyComponent"}, names
    for entity in env.scene.sub_scenes[0].entities:
        for component in entity.components:
            kind = type(component).__name__
            assert "Joint" not in kind and "Drive" not in kind and "Gear" not in kind, (entity.name, kind)


@contextmanager
def no_state_writes(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[str]]:
    """Record every call that would teleport a body or set a joint state (ManiSkill and SAPIEN setters) inside
    the block; the caller asserts the list is empty. Drive targets (what a controller writes) are not recorded."""
    import sapien
    from mani_skill.utils.structs import Actor, Articulation, Link
    from sapien import physx

    calls: list[str] = []

    def recorder(owner: Any, name: str) -> None:
        original = getattr(owner, name)

        def wrapped(*args: Any, **kwargs: Any) -> Any:
            calls.append(f"{owner.__name__}.{name}")
            return original(*args, **kwargs)

        monkeypatch.setattr(owner, name, wrapped)

    for owner, names in ((Actor, ("set_pose", "set_linear_velocity", "set_angular_velocity")),
                         (Link, ("set_pose",)),
                         (Articulation, ("set_qpos", "set_qvel", "set_root_pose", "set_pose")),
                         (sapien.Entity, ("set_pose",)),
                         (physx.PhysxRigidDynamicComponent, ("set_linear_velocity", "set_angular_velocity",
                                                             "set_kinematic", "set_kinematic_target")),
                         (physx.PhysxArticulation, ("set_qpos", "set_qvel", "set_root_pose"))):
        for name in names:
            if hasattr(owner, name):
                recorder(owner, name)
    yield calls
