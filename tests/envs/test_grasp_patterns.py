"""Each grasp pattern's posture, closed on its reference object, holds it by contact alone and reads back as
itself through Eq 6 (the executor-v2 issue, part 1: a grasp pattern's name is a physical law)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mani_skill")

import envs.agents  # noqa: F401  (registers prl_hand)
from envs.executor import PlanExecutor
from envs.tasks.grasp_probe import PROBE_OBJECTS, make_probe_env
from prl import labels
from prl.constants import SENSOR_NAMES
from prl.label_recovery import CONTACT_THRESHOLD_N
from prl.plb import load_plb
from prl.stages import GRASP_POSTURES, STAGES, GraspPosture

#: pattern -> (reference object of envs/tasks/grasp_probe.py, its reference plan)
REFERENCE: dict[str, tuple[str, tuple[int, ...]]] = {o["pattern"]: (kind, o["plan"]) for kind, o in PROBE_OBJECTS.items()}


def test_every_catalogue_pattern_has_a_posture_and_a_reference():
    plb = load_plb()
    assert set(GRASP_POSTURES) == set(plb.dims[3].choices) == set(REFERENCE)
    assert len(REFERENCE) == len(PROBE_OBJECTS)  # one reference object per pattern
    with pytest.raises(ValueError, match="unknown object_kind 'cup'"):
        make_probe_env("cup")
    for kind, plan in REFERENCE.values():
        plb.validate_plan(plan)


def test_closing_windows_by_joint_group():
    from prl.constants import JOINT_NAMES

    start, end = GRASP_POSTURES["medium_wrap"].windows()
    assert start[JOINT_NAMES.index("FFJ3")] == 0.0 and end[JOINT_NAMES.index("FFJ3")] == 0.4
    assert start[JOINT_NAMES.index("LFJ5")] == 0.0 and end[JOINT_NAMES.index("LFJ5")] == 0.4  # goes with J3
    assert (start[JOINT_NAMES.index("RFJ1")], end[JOINT_NAMES.index("RFJ1")]) == (0.3, 0.8)
    assert (start[JOINT_NAMES.index("THJ4")], end[JOINT_NAMES.index("THJ4")]) == (0.5, 1.0)
    assert start[JOINT_NAMES.index("FFJ4")] == 0.0 and end[JOINT_NAMES.index("FFJ4")] == 1.0  # not listed
    assert np.all(start[:8] == 0) and np.all(end[:8] == 1)  # arm and wrist: the whole stage
    bad = GraspPosture(open=np.zeros(22), closed=np.zeros(22), gap=0.0, closing=(("J2", 0.6, 0.4),))
    with pytest.raises(ValueError, match="J2"):
        bad.windows()


@pytest.mark.sim
@pytest.mark.parametrize("pattern", sorted(REFERENCE))
def test_posture_holds_its_reference_object_and_reads_as_itself(pattern):
    plb = load_plb()
    kind, plan = REFERENCE[pattern]
    assert plb.decode(plan)[3] == pattern
    env = make_probe_env(kind)
    try:
        result = PlanExecutor(env).run(plan, seed=0)
    finally:
        env.close()
    # held by contact alone: lifted 4+ cm, and touching sensors all through the lift
    assert result.success, (pattern, result.outcome, result.notes)
    lift = result.stage == STAGES.index("lift")
    contacts = labels.binarize_contacts(result.force[lift], CONTACT_THRESHOLD_N)
    assert contacts.any(axis=1).mean() >= 0.95
    per_record = labels.grasp_label(contacts, plb.grasp_matrix())
    votes = np.bincount(per_record[per_record >= 0], minlength=4)
    commanded = plb.dims[3].index(pattern)
    assert votes[commanded] >= 0.9 * lift.sum(), (pattern, votes)
    # the sensors touching in most of the lift are, by Jaccard, nearest the pattern's own catalogue vector
    held = (contacts.mean(axis=0) >= 0.5).astype(np.uint8)
    assert labels.grasp_label(held, plb.grasp_matrix()) == commanded, [SENSOR_NAMES[i] for i in np.flatnonzero(held)]
