"""Label recovery (docs/guide/design.md "Labels"): hand-built recordings with hand-computed labels, and expert episodes."""

from __future__ import annotations

import json
import re
from types import SimpleNamespace

import numpy as np
import pytest

from prl import label_recovery as LR
from prl import labels
from prl.constants import JOINT_NAMES, SENSOR_NAMES
from prl.demo import load_demo
from prl.plb import load_plb

EXPERT = [0, 3, 2, 0, 0, 1]
"""rot X 0, rot Z 0, anchor 2, medium wrap, wrist horizontal swing, object Z || T_fv Y."""
STAGE_RECORDS = (10, 4, 6, 6, 10, 5, 18)
"""Records per stage (pregrasp .. motion) of the synthetic recordings."""


@pytest.fixture(scope="module")
def bank():
    return load_plb()


# ----------------------------------------------------------------------------- helpers


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The quaternion of the rotation ``a`` then (in its frame) ``b``: R(a) R(b)."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def quat_axis(axis: str, deg: float) -> np.ndarray:
    """[qw, qx, qy, qz] of a rotation by ``deg`` about world ``axis``."""
    h = np.deg2rad(deg) / 2
    q = np.zeros(4)
    q[0] = np.cos(h)
    q[1 + "xyz".index(axis)] = np.sin(h)
    return q


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product (rotation a then, in a's frame, b: matrix R(a) @ R(b))."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def forces(names: tuple[str, ...], value: float = 5.0) -> np.ndarray:
    f = np.zeros(len(SENSOR_NAMES))
    f[[SENSOR_NAMES.index(n) for n in names]] = value
    return f


def joint(name: str) -> int:
    return JOINT_NAMES.index(name)


IDENTITY_Q = np.array([1.0, 0.0, 0.0, 0.0])
GV_CENTER = np.array([0.0, 0.0, 0.1])
GV_HALF = np.array([0.11, 0.018, 0.018])
FV_LOCAL = np.array([0.13, 0.0, 0.0, 0.017, 0.034, 0.017])
WRAP_CONTACTS = ("palm", "ff_distal", "mf_distal", "rf_distal", "lf_metacarpal", "lf_proximal", "lf_distal")
"""What the executor's medium wrap touches the handle with (measured on the expert plan, seed 0)."""


def synthetic_demo(palm_q: np.ndarray = IDENTITY_Q, lift_force: np.ndarray | None = None,
                   motion_dq: np.ndarray | None = None, object_q: np.ndarray = IDENTITY_Q,
                   anchor_on_line: int = 3, anchors_with_palm: bool = False) -> SimpleNamespace:
    """A hand-built recording: tool at the identity, palm at ``palm_q`` from the pregrasp on, the
    contact pattern ``lift_force`` during the grasp and lift, a held tool whose T_fv reaches the object
    (rotation ``object_q``) in the motion stage, and ``motion_dq`` spread over the motion stage. With
    ``anchors_with_palm`` the anchor grid turns with the palm, as the executor places it: anchor
    ``anchor_on_line`` 3 cm out along the palm's normal, the others in the palm's plane."""
    stage = np.concatenate([np.full(n, s) for s, n in enumerate(STAGE_RECORDS)])
    t = len(stage)
    held = forces(WRAP_CONTACTS) if lift_force is None else lift_force
    force = np.zeros((t, len(SENSOR_NAMES)))
    force[stage >= 2] = held
    palm_pose = np.tile(np.concatenate([[0.0, 0.05, 0.1], palm_q]), (t, 1))
    tool_pose = np.tile(np.concatenate([[0.0, 0.0, 0.1], IDENTITY_Q]), (t, 1))
    # the object's frame sits 20 cm away, except for one motion record where T_fv's face touches it
    object_pose = np.tile(np.concatenate([[0.5, 0.0, 0.0], object_q]), (t, 1))
    motion = np.nonzero(stage == 6)[0]
    object_pose[motion[8], :3] = tool_pose[motion[8], :3] + FV_LOCAL[:3] + [0.0, 0.0, -FV_LOCAL[5]]
    qpos = np.zeros((t, len(JOINT_NAMES)))
    if motion_dq is not None:
        ramp = np.clip((np.arange(len(motion)) - 3) / 8, 0, 1)
        qpos[motion] = ramp[:, None] * motion_dq
    # anchors: a 3 x 2 grid 3 cm above T_gv along +Y, with anchor ``anchor_on_line`` straight above the centre
    grid = np.array([[0.016, 0.085], [-0.016, 0.085], [0.016, 0.060], [-0.016, 0.060], [0.016, 0.035], [-0.016, 0.035]])
    grid = grid - grid[anchor_on_line]
    anchors = np.stack([grid[:, 0], np.full(6, 0.03), grid[:, 1]], axis=1)
    anchors = GV_CENTER + (anchors @ LR.quat_to_matrix(palm_q).T if anchors_with_palm else anchors)
    return SimpleNamespace(
        stage=stage, qpos=qpos, qvel=np.zeros_like(qpos), force=force, palm_pose=palm_pose, tool_pose=tool_pose,
        object_pose=object_pose, anchors_at_grasp=anchors, gv_center=GV_CENTER, gv_half=GV_HALF, gv_rot=np.eye(3),
        tool_gv_local=np.concatenate([np.zeros(3), GV_HALF]), tool_fv_local=FV_LOCAL,
    )


# ----------------------------------------------------------------------------- fast, no simulation


def test_quat_to_matrix_hand_values():
    R = LR.quat_to_matrix(quat_axis("z", 90))
    assert np.allclose(R, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    R = LR.quat_to_matrix(2 * quat_axis("x", 90))  # not unit: normalised first
    assert np.allclose(R, [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)


def test_point_box_distance_hand_values():
    c, h = np.zeros(3), np.array([0.1, 0.02, 0.02])
    assert LR.point_box_distance(np.array([0.05, 0.0, 0.0]), c, h, np.eye(3)) == 0.0
    assert np.isclose(LR.point_box_distance(np.array([0.0, 0.05, 0.0]), c, h, np.eye(3)), 0.03)
    rz90 = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])  # box long axis along world Y
    assert np.isclose(LR.point_box_distance(np.array([0.0, 0.15, 0.0]), c, h, rz90), 0.05)


def test_rotation_minus10_x_plus20_z(bank):
    """Palm = T_gv Rx(-10) Rz(20): a0 = -10 deg (index 2), a1 = 20 deg (index 5)."""
    demo = synthetic_demo(palm_q=qmul(quat_axis("x", -10), quat_axis("z", 20)))
    out = LR.recover_plan(demo, bank)
    assert np.allclose(out.euler_contact_deg, [-10, 0, 20], atol=1e-9)
    assert out.plan[0] == 2 and out.plan[1] == 5
    assert bank.dims[0].choices[2] == -10 and bank.dims[1].choices[5] == 20


def test_rotation_read_before_first_contact(bank):
    """A push after the first touch (palm turned to Rx(-25)) does not change a0: the pre-contact record is used."""
    demo = synthetic_demo()
    k = np.nonzero(demo.stage == 1)[0][2]  # the third approach record touches
    demo.force[k:] = forces(("palm", "th_distal"))
    demo.palm_pose[k:, 3:] = quat_axis("x", -25)
    out = LR.recover_plan(demo, bank)
    assert out.contact_record == k - 1
    assert out.plan[0] == 0 and out.plan[1] == 3
    assert np.isclose(out.euler_grasp_deg[0], -25)


def test_rotation_class_boundary(bank):
    """Eq 4 with c = 5: -12.4 deg is class -2 (-10 deg, index 2), -12.6 deg class -3 (-15 deg, index 3)."""
    assert LR.recover_plan(synthetic_demo(palm_q=quat_axis("x", -12.4)), bank).plan[0] == 2
    assert LR.recover_plan(synthetic_demo(palm_q=quat_axis("x", -12.6)), bank).plan[0] == 3


@pytest.mark.parametrize("anchor", range(6))
def test_anchor_above_gv_centre(bank, anchor):
    out = LR.recover_plan(synthetic_demo(anchor_on_line=anchor), bank)
    assert out.plan[2] == anchor
    assert out.anchor_face == 2 and np.isclose(out.anchor_cos, 1.0)  # the +Y face, exactly parallel


@pytest.mark.parametrize("anchor", range(6))
def test_a_tilted_and_twisted_palm_reads_its_own_anchor(bank, anchor):
    """The tweeze expert's palm (Rx -10 deg, then Rz -20 deg relative to T_gv): Eq 5 with T_gv's faces turned with
    the palm reads the anchor on the palm's normal; in the tool's own frame some anchors read a neighbour."""
    palm_q = quat_mul(quat_axis("x", -10), quat_axis("z", -20))
    demo = synthetic_demo(palm_q=palm_q, anchor_on_line=anchor, anchors_with_palm=True)
    out = LR.recover_plan(demo, bank)
    assert out.plan[2] == anchor and np.isclose(out.anchor_cos, 1.0)
    assert out.plan[:2].tolist() == [2, 1]  # a0 = -10 deg, a1 = -20 deg


def test_in_the_tools_frame_a_tilted_palm_reads_a_neighbouring_anchor(bank):
    """What Eq 5 gave before it turned T_gv's faces with the palm: with the palm tilted by -30 deg about the handle
    (this grid: rows 2.5 cm apart, 3 cm out), the next row leans 10 deg off the face normal, the commanded anchor
    30 deg; turned with the palm, the commanded anchor is back on the face normal."""
    demo = synthetic_demo(palm_q=quat_axis("x", -30), anchor_on_line=2, anchors_with_palm=True)
    faces = labels.box_face_centers(GV_CENTER, GV_HALF, np.eye(3))
    assert labels.relative_position_label(GV_CENTER, faces, demo.anchors_at_grasp)[1] != 2
    assert LR.recover_plan(demo, bank).plan[2] == 2


def test_grasp_pattern_from_lift_contacts(bank):
    """ff_middle, ff_distal, th_distal at 5 N and a 0.5 N graze (under the 1 N threshold): palmar pinch, Jaccard
    2/4 with its catalogue vector [ff_distal, th_middle, th_distal], 1/7 with the precision disk."""
    f = forces(("ff_middle", "ff_distal", "th_distal")) + forces(("palm",), 0.5)
    out = LR.recover_plan(synthetic_demo(lift_force=f), bank)
    assert out.plan[3] == bank.dims[3].index("palmar_pinch")
    assert np.isclose(out.grasp_jaccard[bank.dims[3].index("palmar_pinch")], 0.5)
    assert np.isclose(out.grasp_jaccard[bank.dims[3].index("precision_disk")], 1 / 7)


def test_a_pinch_with_the_thumbs_middle_phalanx_reads_as_a_pinch(bank):
    """The tweeze expert's held contacts, ff_distal and th_middle: Jaccard 2/3 with the palmar pinch, 2/5 with
    the precision disk (with the pinch's vector of before, [ff_middle, ff_distal, th_distal]: 1/4, a disk)."""
    out = LR.recover_plan(synthetic_demo(lift_force=forces(("ff_distal", "th_middle"))), bank)
    assert out.plan[3] == bank.dims[3].index("palmar_pinch")
    assert np.isclose(out.grasp_jaccard[bank.dims[3].index("palmar_pinch")], 2 / 3)
    assert np.isclose(out.grasp_jaccard[bank.dims[3].index("precision_disk")], 0.4)
    assert out.contact_fraction[SENSOR_NAMES.index("palm")] == 0.0


def test_executor_wrap_contacts_read_as_medium_wrap(bank):
    """The contacts of the executor's medium wrap: Jaccard 7/10 with medium wrap, 4/8 with precision disk."""
    out = LR.recover_plan(synthetic_demo(), bank)
    wrap, disk = bank.dims[3].index("medium_wrap"), bank.dims[3].index("precision_disk")
    assert out.plan[3] == wrap
    assert np.isclose(out.grasp_jaccard[wrap], 7 / 10) and np.isclose(out.grasp_jaccard[disk], 4 / 8)


def test_no_contact_in_lift_gives_minus_one(bank):
    out = LR.recover_plan(synthetic_demo(lift_force=np.zeros(len(SENSOR_NAMES))), bank)
    assert out.plan[3] == -1 and out.plan[5] == -1
    assert any("a3" in n for n in out.notes) and any("a5" in n for n in out.notes)


def test_motion_along_wrj1_is_wrist_horizontal(bank):
    dq = np.zeros(len(JOINT_NAMES))
    dq[joint("WRJ1")] = -0.7
    dq[joint("FFJ2")] = 0.05  # a little finger slip
    demo = synthetic_demo(motion_dq=dq)
    rng = np.random.default_rng(0)
    demo.qvel = rng.normal(0, 2.0, demo.qvel.shape)  # chatter in the instantaneous velocities is ignored
    out = LR.recover_plan(demo, bank)
    assert out.plan[4] == bank.dims[4].index("wrist_horizontal")
    assert np.argmax(out.motion_cosine) == [t.name for t in bank.motion_templates].index("wrist_horizontal-")


def test_motion_finger_squeeze_and_none(bank):
    dq = np.zeros(len(JOINT_NAMES))
    for f in ("FF", "MF", "RF", "LF"):
        for j in (3, 2, 1):
            dq[joint(f"{f}J{j}")] = 0.18
    dq[joint("ARTz")] = -0.03
    assert LR.recover_plan(synthetic_demo(motion_dq=dq), bank).plan[4] == bank.dims[4].index("finger_squeeze")
    dq = np.zeros(len(JOINT_NAMES))
    dq[joint("THJ3")] = 0.005  # below MIN_MOTION_NORM: no motion
    out = LR.recover_plan(synthetic_demo(motion_dq=dq), bank)
    assert out.plan[4] == -1


def test_object_z_along_tool_x_plus_z(bank):
    """Object rotated Ry(45): its Z is (X + Z)/sqrt 2 in the (identity) tool frame -> X-Z."""
    out = LR.recover_plan(synthetic_demo(object_q=quat_axis("y", 45)), bank)
    assert out.plan[5] == bank.dims[5].index("X-Z")
    assert np.allclose(out.object_z_in_tool, np.array([1, 0, 1]) / np.sqrt(2))
    assert np.isclose(out.tool_object_angle_deg, 0.0, atol=1e-6)


def test_object_axis_read_where_held_tool_is_closest(bank):
    """Only the record where the held T_fv reaches the object counts; a closer, unheld record does not."""
    demo = synthetic_demo(object_q=quat_axis("x", 90))  # object Z = world -Y: T_fv Y
    motion = np.nonzero(demo.stage == 6)[0]
    demo.object_pose[motion[:8], 3:] = quat_axis("y", 90)  # before the contact: object Z = tool X
    late = motion[12]
    demo.object_pose[late, :3] = demo.tool_pose[late, :3] + FV_LOCAL[:3]  # inside T_fv ...
    demo.object_pose[late, 3:] = quat_axis("y", 90)
    demo.force[late] = forces(("th_distal",))  # ... but only one sensor touches: not held
    out = LR.recover_plan(demo, bank)
    assert out.tool_object_record == motion[8]
    assert out.plan[5] == bank.dims[5].index("Y")


def test_recovery_never_reads_the_plan(bank):
    demo = synthetic_demo()
    assert not hasattr(demo, "plan")
    out = LR.recover_plan(demo, bank)
    assert out.plan.dtype == np.int64 and out.plan.shape == (6,)
    assert out.plan.tolist() == [0, 3, 3, 0, -1, 2]  # no motion given; object Z = tool Z


def test_missing_field_and_bad_shapes_are_named(bank):
    demo = synthetic_demo()
    del demo.force
    with pytest.raises(ValueError, match="force"):
        LR.recover_plan(demo, bank)
    demo = synthetic_demo()
    demo.qpos = demo.qpos[:-1]
    with pytest.raises(ValueError, match="qpos"):
        LR.recover_plan(demo, bank)


def test_agreement_hand_values():
    commanded = [[0, 1, 2], [3, 4, 5], [0, 0, 0], [1, 1, 1]]
    recovered = [[0, 1, -1], [3, 0, 5], [0, 0, 0], [2, 1, -1]]
    assert np.allclose(LR.agreement(commanded, recovered), [0.75, 0.75, 0.5])
    with pytest.raises(ValueError, match="shape"):
        LR.agreement([[0, 1]], [[0, 1, 2]])
    with pytest.raises(ValueError, match="N = 0"):
        LR.agreement(np.zeros((0, 6)), np.zeros((0, 6)))


def test_format_agreement(bank):
    text = LR.format_agreement(np.array([1.0, 0.5, 0.25, 0.0, 0.9, 1.0]), 20, bank)
    lines = text.splitlines()
    assert "20 demos" in lines[0]
    assert "a1 hand_tool_rot_z" in lines[2] and "50.0%" in lines[2] and "(10/20)" in lines[2]
    assert "a3 grasp_pattern" in lines[4] and "0.0%" in lines[4]
    with pytest.raises(ValueError, match="6 fractions"):
        LR.format_agreement(np.ones(5), 3, bank)


def _save(demo: SimpleNamespace, plan: list[int], success: bool, path) -> None:
    """Write ``demo`` in the prl.demo file layout (header JSON + arrays)."""
    header = {"task": "hammer", "seed": 0, "text": "", "success": success, "outcome": {}, "scene_params": {}}
    arrays = {k: v for k, v in vars(demo).items()} | {"plan": np.asarray(plan, dtype=np.int64)}
    np.savez_compressed(path, header=np.frombuffer(json.dumps(header).encode(), dtype=np.uint8), **arrays)


def test_cli_successful_demos_only_by_default(tmp_path, capsys):
    dq = np.zeros(len(JOINT_NAMES))
    dq[joint("WRJ1")] = 0.7
    (tmp_path / "ok").mkdir()
    (tmp_path / "fail").mkdir()
    _save(synthetic_demo(motion_dq=dq), [0, 3, 3, 3, 0, 0], True, tmp_path / "ok" / "a.npz")
    _save(synthetic_demo(motion_dq=dq), [0, 3, 3, 0, 0, 0], True, tmp_path / "ok" / "b.npz")
    _save(synthetic_demo(), [1, 1, 1, 1, 1, 1], False, tmp_path / "fail" / "c.npz")
    assert LR.main([str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "over 2 demos" in out
    assert re.search(r"a0 hand_tool_rot_x\s+100\.0%", out) and re.search(r"a3 grasp_pattern\s+50\.0%", out)
    assert re.search(r"a5 tool_object_rot\s+0\.0%", out)  # object Z = tool Z, commanded X
    assert LR.main([str(tmp_path), "--all"]) == 0
    assert "over 3 demos" in capsys.readouterr().out
    rec = load_demo(tmp_path / "ok" / "a.npz")
    assert rec.success and rec.plan.tolist() == [0, 3, 3, 3, 0, 0]
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        load_demo(tmp_path / "nope.npz")


# ----------------------------------------------------------------------------- simulation


@pytest.fixture(scope="module")
def expert_demos():
    pytest.importorskip("mani_skill")
    import envs.agents  # noqa: F401
    from envs.executor import PlanExecutor
    from envs.tasks import make_env
    from prl.demo import from_episode
    from prl.stages import STAGES

    assert STAGES == LR.STAGES
    env = make_env("hammer")
    try:
        executor = PlanExecutor(env)
        demos = [from_episode("hammer", seed, "", executor.run(EXPERT, seed=seed), env) for seed in (0, 1, 2)]
    finally:
        env.close()
    return demos


@pytest.mark.sim
def test_expert_episodes_recover_plan(expert_demos, bank):
    """Every dimension of the expert plan is recovered from the recording alone, the grasp pattern included."""
    for demo in expert_demos:
        out = LR.recover_plan(demo, bank)
        assert demo.success, demo.outcome
        got = out.plan.tolist()
        assert [got[i] for i in (0, 1, 2, 4, 5)] == [EXPERT[i] for i in (0, 1, 2, 4, 5)], (got, out)
        assert np.all(np.abs(out.euler_contact_deg) < 1.0), out.euler_contact_deg
        assert got[3] == bank.dims[3].index("medium_wrap"), (got, out.grasp_jaccard)
        assert out.tool_object_angle_deg < 15.0  # 11.4 deg on seed 0 (the classes are 45 deg apart)
    frac = LR.agreement([d.plan for d in expert_demos], [LR.recover_plan(d, bank).plan for d in expert_demos])
    assert frac.tolist() == [1.0] * 6


def test_agreement_by_another_dimension_hand_values(bank):
    commanded = np.array([[0, 0, 1, 0, 0, 0], [0, 0, 2, 0, 0, 0], [6, 0, 3, 0, 0, 0], [6, 0, 4, 0, 0, 0]])
    recovered = np.array([[0, 0, 1, 0, 0, 0], [0, 0, 2, 0, 0, 0], [6, 0, 1, 0, 0, 0], [6, 0, 4, 0, 0, 0]])
    text = LR.format_agreement_by(commanded, recovered, 2, 0, bank)
    assert "a2 hand_tool_anchor agreement by commanded a0" in text
    assert "0: 2/2 = 1.00" in text and "-30: 1/2 = 0.50" in text and "-5:" not in text  # absent choices skipped
    with pytest.raises(ValueError, match="got 9"):
        LR.format_agreement_by(commanded, recovered, 9, 0, bank)
