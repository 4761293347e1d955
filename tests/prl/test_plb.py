"""Fast tests of the Physical Laws Bank catalogue and plan conversions (no simulation)."""

from __future__ import annotations

import copy
import dataclasses
import pickle
from pathlib import Path

import numpy as np
import pytest
import yaml

from prl import plb as plb_mod
from prl.constants import JOINT_NAMES, RS_DIMS, SENSOR_NAMES, TASKS
from prl.plb import DEFAULT_PLB_PATH, PhysicalLawsBank, PLBError, load_plb

HAMMER_CHOICES = {
    "hand_tool_rot_x": 0,
    "hand_tool_rot_z": 0,
    "hand_tool_anchor": 2,
    "grasp_pattern": "medium_wrap",
    "kinematic_motion": "wrist_horizontal",
    "tool_object_rot": "Y",
}


@pytest.fixture(scope="module")
def bank() -> PhysicalLawsBank:
    return load_plb()


@pytest.fixture
def raw() -> dict:
    """A fresh, editable copy of the shipped catalogue document."""
    return copy.deepcopy(yaml.safe_load(DEFAULT_PLB_PATH.read_text(encoding="utf-8")))


def write(tmp_path: Path, doc: dict) -> Path:
    path = tmp_path / "plb.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    return path


# ----------------------------------------------------------------- catalogue


def test_dimensions_match_table_ii(bank):
    assert bank.dim_names == (
        "hand_tool_rot_x",
        "hand_tool_rot_z",
        "hand_tool_anchor",
        "grasp_pattern",
        "kinematic_motion",
        "tool_object_rot",
    )
    assert bank.sizes == (7, 7, 6, 4, 7, 6)
    assert len(bank.dims) == len(RS_DIMS)
    assert bank.n_plans == 49392 == int(np.prod(RS_DIMS))
    assert bank.dims[0].choices == (0, -5, -10, -15, -20, -25, -30)
    assert bank.dims[0].class_constant == 5.0
    assert bank.dims[1].choices == (-30, -20, -10, 0, 10, 20, 30)
    assert bank.dims[1].class_constant == 10.0
    assert bank.dims[2].class_constant is None
    assert bank.dims[5].choices == ("X", "Y", "Z", "X-Y", "X-Z", "Y-Z")


def test_grasp_matrix(bank):
    g = bank.grasp_matrix()
    assert g.shape == (4, 17) and g.dtype == np.uint8
    pinch = [SENSOR_NAMES.index(s) for s in ("ff_distal", "th_middle", "th_distal")]
    expected = np.zeros(17, dtype=np.uint8)
    expected[pinch] = 1
    np.testing.assert_array_equal(g[2], expected)
    assert g[0, SENSOR_NAMES.index("palm")] == 1  # medium wrap is a power grasp
    assert g[1, SENSOR_NAMES.index("palm")] == 0  # parallel extension: no palm
    assert g.sum(axis=1).tolist() == [10, 10, 3, 5]
    assert len({row.tobytes() for row in g}) == 4


def test_grasp_matrix_is_a_fresh_copy(bank):
    g = bank.grasp_matrix()
    g[:] = 0
    assert bank.grasp_matrix().sum() == 28


def test_motion_templates(bank):
    t = bank.template_matrix()
    assert t.shape == (13, 30)
    wrj1 = JOINT_NAMES.index("WRJ1")
    assert t[0, wrj1] == 1.0 and t[1, wrj1] == -1.0
    assert np.count_nonzero(t[:12], axis=1).tolist() == [1] * 12
    assert t[11, JOINT_NAMES.index("ARRz")] == -1.0
    squeeze = {JOINT_NAMES[i] for i in np.flatnonzero(t[12])}
    assert squeeze == {f"{f}J{j}" for f in ("FF", "MF", "RF", "LF") for j in (3, 2, 1)} | {"THJ1", "THJ2"}
    assert bank.template_to_motion.tolist() == [0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6]


def test_priors_are_positive_distributions(bank):
    for task in TASKS:
        prior = bank.prior(task)
        assert [len(p) for p in prior] == list(bank.sizes)
        for p in prior:
            assert np.all(p > 0)
            assert p.sum() == pytest.approx(1.0)
        assert 3 <= len(bank.texts(task)) <= 5


@pytest.mark.parametrize(
    ("task", "grasp", "motion"),
    [
        ("hammer", "medium_wrap", "wrist_horizontal"),
        ("sweep", "medium_wrap", "arm_linear_x"),
        ("unscrew", "precision_disk", "arm_rotate_palm"),  # a 6.4-7.6 cm cap is the precision disk's object
        ("tweeze", "palmar_pinch", "finger_squeeze"),
    ],
)
def test_prior_modes_are_sensible(bank, task, grasp, motion):
    prior = bank.prior(task)
    assert bank.dim("grasp_pattern").choices[int(np.argmax(prior[3]))] == grasp
    assert bank.dim("kinematic_motion").choices[int(np.argmax(prior[4]))] == motion


def test_bank_is_immutable_and_picklable(bank):
    with pytest.raises(dataclasses.FrozenInstanceError):
        bank.dims = ()  # type: ignore[misc]
    assert pickle.loads(pickle.dumps(bank)) == bank


def test_load_is_cached_and_default_path(bank):
    assert load_plb() is bank
    assert load_plb(DEFAULT_PLB_PATH) is bank


# --------------------------------------------------------------------- plans


def test_describe_matches_example(bank):
    text = bank.describe([0, 3, 2, 0, 0, 1], task="hammer")
    assert text == (
        "hammer plan [0,3,2,0,0,1]: rotate X 0 deg, rotate Z 0 deg, anchor 2, "
        "medium wrap, wrist horizontal, object Z || T_fv Y"
    )
    assert bank.describe(np.array([1, 0, 5, 2, 6, 3])) == (
        "plan [1,0,5,2,6,3]: rotate X -5 deg, rotate Z -30 deg, anchor 5, "
        "palmar pinch, finger squeeze, object Z || T_fv X-Y"
    )
    assert plb_mod.describe([0, 3, 2, 0, 0, 1], "hammer") == text


def test_encode_decode(bank):
    np.testing.assert_array_equal(bank.encode(HAMMER_CHOICES), [0, 3, 2, 0, 0, 1])
    v = bank.encode([-5.0, 30, 5, "Palmar Pinch", "finger squeeze", "y-z"])
    assert v.dtype == np.int64
    assert v.tolist() == [1, 6, 5, 2, 6, 5]
    assert bank.decode(v) == [-5, 30, 5, "palmar_pinch", "finger_squeeze", "Y-Z"]
    assert plb_mod.encode(bank.decode([6, 0, 0, 3, 5, 2])).tolist() == [6, 0, 0, 3, 5, 2]


def test_encode_errors(bank):
    with pytest.raises(PLBError, match="unknown grasp_pattern 'medium_wrapp'"):
        bank.encode({**HAMMER_CHOICES, "grasp_pattern": "medium_wrapp"})
    with pytest.raises(PLBError, match=r"unknown hand_tool_rot_x -7.*allowed: 0, -5"):
        bank.encode({**HAMMER_CHOICES, "hand_tool_rot_x": -7})
    with pytest.raises(PLBError, match=r"missing dimensions \['tool_object_rot'\]"):
        bank.encode({k: v for k, v in HAMMER_CHOICES.items() if k != "tool_object_rot"})
    with pytest.raises(PLBError, match=r"unknown dimensions \['colour'\]"):
        bank.encode({**HAMMER_CHOICES, "colour": "red"})
    with pytest.raises(PLBError, match="expected 6 choices"):
        bank.encode([0, 0, 2])


def test_validate_plan(bank):
    plan = np.array([6, 6, 5, 3, 6, 5], dtype=np.int32)
    out = bank.validate_plan(plan)
    assert out.dtype == np.int64 and out.tolist() == [6, 6, 5, 3, 6, 5]
    out[0] = 0
    assert plan[0] == 6  # a copy, not a view


@pytest.mark.parametrize(
    ("plan", "match"),
    [
        ([0, 3, 2, 0, 0], r"6 entries .* got 5"),
        ([0, 3, 2, 0, 0, 1, 0], r"6 entries .* got 7"),
        ([0, 3, 2, 4, 0, 1], r"grasp_pattern is 4, out of range; allowed 0\.\.3"),
        ([-1, 3, 2, 0, 0, 1], r"hand_tool_rot_x is -1, out of range; allowed 0\.\.6"),
        ([0, 3, 2, 0, 7, 1], r"kinematic_motion is 7, out of range; allowed 0\.\.6"),
        ([0, 3, 2.0, 0, 0, 1], r"hand_tool_anchor must be an integer index, got 2\.0"),
        ([0, 3, 2, "0", 0, 1], r"grasp_pattern must be an integer index, got '0'"),
        ([True, 3, 2, 0, 0, 1], r"hand_tool_rot_x must be an integer index, got True"),
        (5, r"sequence of 6 integers, got 5"),
    ],
)
def test_validate_plan_errors(bank, plan, match):
    with pytest.raises(PLBError, match=match):
        bank.validate_plan(plan)


def test_unknown_task(bank):
    with pytest.raises(PLBError, match="unknown task 'drill'"):
        bank.describe([0, 3, 2, 0, 0, 1], task="drill")
    with pytest.raises(PLBError, match="unknown task 'drill'"):
        bank.sample_plan("drill", np.random.default_rng(0))
    with pytest.raises(PLBError, match="unknown dimension 'colour'"):
        bank.dim("colour")


def test_sample_plan_deterministic_and_follows_prior(bank):
    a = [bank.sample_plan("hammer", np.random.default_rng(7)) for _ in range(2)]
    np.testing.assert_array_equal(a[0], a[1])
    rng = np.random.default_rng(0)
    plans = np.stack([plb_mod.sample_plan("tweeze", rng) for _ in range(2000)])
    assert plans.shape == (2000, 6) and plans.dtype == np.int64
    assert np.all(plans >= 0) and np.all(plans < np.array(bank.sizes))
    freq = np.bincount(plans[:, 3], minlength=4) / len(plans)
    np.testing.assert_allclose(freq, bank.prior("tweeze")[3], atol=0.04)
    with pytest.raises(TypeError, match="numpy.random.Generator"):
        bank.sample_plan("hammer", 0)  # type: ignore[arg-type]


# ------------------------------------------------------- catalogue errors


def test_shipped_catalogue_roundtrips_through_yaml(tmp_path, raw):
    assert load_plb(write(tmp_path, raw)) == load_plb()


def test_missing_file(tmp_path):
    missing = tmp_path / "nope" / "plb.yaml"
    with pytest.raises(PLBError, match=f"not found: {missing}"):
        load_plb(missing)


def test_malformed_yaml(tmp_path):
    path = tmp_path / "plb.yaml"
    path.write_text("dimensions: [\n  - {name: a\n", encoding="utf-8")
    with pytest.raises(PLBError, match="malformed YAML"):
        load_plb(path)


def test_top_level_not_a_mapping(tmp_path):
    path = tmp_path / "plb.yaml"
    path.write_text("- just\n- a list\n", encoding="utf-8")
    with pytest.raises(PLBError, match="mapping at top level, got list"):
        load_plb(path)


def test_typo_sensor_name(tmp_path, raw):
    raw["grasp_patterns"]["palmar_pinch"]["sensors"] = ["ff_distal", "th_distl"]
    with pytest.raises(PLBError, match="grasp pattern 'palmar_pinch': unknown sensor 'th_distl'") as err:
        load_plb(write(tmp_path, raw))
    assert str(tmp_path) in str(err.value)


def test_unknown_joint_name(tmp_path, raw):
    raw["motion_templates"][0]["joint_velocity"] = {"WRJ3": 1.0}
    with pytest.raises(PLBError, match="motion template 'wrist_horizontal\\+': unknown joint 'WRJ3'"):
        load_plb(write(tmp_path, raw))


def test_unknown_motion_in_template(tmp_path, raw):
    raw["motion_templates"][0]["motion"] = "wrist_twist"
    with pytest.raises(PLBError, match="unknown kinematic_motion 'wrist_twist'"):
        load_plb(write(tmp_path, raw))


def test_motion_without_template(tmp_path, raw):
    raw["motion_templates"] = raw["motion_templates"][:12]
    with pytest.raises(
        PLBError, match=r"no motion template for kinematic_motion choices \['finger_squeeze'\]"
    ):
        load_plb(write(tmp_path, raw))


def test_wrong_number_of_dimensions(tmp_path, raw):
    del raw["dimensions"][2]
    with pytest.raises(PLBError, match="expected 6 dimensions, got 5"):
        load_plb(write(tmp_path, raw))


def test_missing_key(tmp_path, raw):
    del raw["grasp_patterns"]
    with pytest.raises(PLBError, match="catalogue: missing key 'grasp_patterns'"):
        load_plb(write(tmp_path, raw))
    raw = yaml.safe_load(DEFAULT_PLB_PATH.read_text(encoding="utf-8"))
    del raw["dimensions"][1]["choices"]
    with pytest.raises(PLBError, match=r"dimensions\[1\]: missing key 'choices'"):
        load_plb(write(tmp_path, raw))


def test_grasp_patterns_must_match_choices(tmp_path, raw):
    raw["grasp_patterns"]["tripod"] = raw["grasp_patterns"].pop("precision_disk")
    with pytest.raises(PLBError, match=r"missing \['precision_disk'\], unknown \['tripod'\]"):
        load_plb(write(tmp_path, raw))


def test_prior_not_summing_to_one(tmp_path, raw):
    raw["tasks"]["hammer"]["prior"]["grasp_pattern"] = [0.7, 0.2, 0.2, 0.1]
    with pytest.raises(PLBError, match=r"task 'hammer' prior for grasp_pattern: probabilities sum to 1\.2"):
        load_plb(write(tmp_path, raw))


def test_prior_wrong_length(tmp_path, raw):
    raw["tasks"]["sweep"]["prior"]["tool_object_rot"] = [0.5, 0.5]
    with pytest.raises(PLBError, match="task 'sweep' prior for tool_object_rot: 2 probabilities, expected 6"):
        load_plb(write(tmp_path, raw))


def test_prior_negative(tmp_path, raw):
    raw["tasks"]["tweeze"]["prior"]["grasp_pattern"] = [-0.1, 0.3, 0.6, 0.2]
    with pytest.raises(PLBError, match=r"must be finite and >= 0, got \[-0\.1"):
        load_plb(write(tmp_path, raw))


def test_prior_missing_dimension(tmp_path, raw):
    del raw["tasks"]["unscrew"]["prior"]["hand_tool_anchor"]
    with pytest.raises(PLBError, match=r"tasks.unscrew.prior: missing dimensions \['hand_tool_anchor'\]"):
        load_plb(write(tmp_path, raw))


def test_missing_task(tmp_path, raw):
    del raw["tasks"]["tweeze"]
    with pytest.raises(PLBError, match="missing task 'tweeze'"):
        load_plb(write(tmp_path, raw))


def test_duplicate_choice(tmp_path, raw):
    raw["dimensions"][1]["choices"] = [-30, -20, -10, 0, 10, 20, 20]
    with pytest.raises(PLBError, match="'hand_tool_rot_z' has duplicate choices"):
        load_plb(write(tmp_path, raw))


def test_rs_dims_constant_matches_catalogue() -> None:
    """prl.constants.RS_DIMS follows the catalogue (Table II rows: motion 7, tool-object rot 6)."""
    assert load_plb().sizes == RS_DIMS == (7, 7, 6, 4, 7, 6)


def test_a_task_variant_reads_its_own_entry_or_its_tasks() -> None:
    plb = load_plb()
    assert plb.task("sweep_mixed") is plb.task("sweep")
    assert plb.texts("tweeze_wide") == plb.texts("tweeze")
    # hammer_mixed has an entry of its own: the slanted nails' push (arm_linear_x, object Z || T_fv X) weighs
    # 0.105 against the wrist swing's 0.1225 (object Z || T_fv Y), where the hammer's prior gives 0.005 and 0.275
    assert plb.task("hammer_mixed").name == "hammer_mixed" and plb.texts("hammer_mixed") != plb.texts("hammer")
    for task, push, swing in (("hammer_mixed", 0.30 * 0.35, 0.35 * 0.35), ("hammer", 0.05 * 0.10, 0.55 * 0.50)):
        motion, axis = plb.prior(task)[4:6]
        assert (motion[2] * axis[0], motion[0] * axis[1]) == pytest.approx((push, swing))
    for name in ("drill_mixed", "hammer_", "_hammer"):
        with pytest.raises(PLBError, match=f"unknown task {name!r}"):
            plb.task(name)
