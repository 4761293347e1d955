"""Fast tests of the label maths (paper Appendix Eqs 4-9) against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from prl import labels as L
from prl.constants import JOINT_NAMES, SENSOR_NAMES
from prl.plb import load_plb

S2 = np.sqrt(0.5)
RX90 = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
RZ90 = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])


@pytest.fixture(scope="module")
def bank():
    return load_plb()


def contacts(*names: str) -> np.ndarray:
    v = np.zeros(len(SENSOR_NAMES), dtype=np.uint8)
    v[[SENSOR_NAMES.index(n) for n in names]] = 1
    return v


def velocity(**joints: float) -> np.ndarray:
    v = np.zeros(len(JOINT_NAMES))
    for name, value in joints.items():
        v[JOINT_NAMES.index(name)] = value
    return v


# ------------------------------------------------------------------- Eq 4


def test_rotation_class_rounds_half_up():
    theta = [0.0, 2.4, 2.5, -2.5, -2.6, 7.5, -7.5, 12.4, -30.0]
    assert L.rotation_class(theta, 5).tolist() == [0, 0, 1, 0, -1, 2, -1, 2, -6]
    assert L.rotation_class(np.array([15.0, -15.0, 175.0, 180.0]), 10).tolist() == [2, -1, 18, 18]
    assert L.rotation_class(4.99, 10).dtype == np.int64
    with pytest.raises(ValueError, match="c must be > 0, got 0"):
        L.rotation_class(1.0, 0)


def test_rotation_choice_maps_and_clips():
    a0 = [0, -5, -10, -15, -20, -25, -30]
    got = L.rotation_choice([0.0, -7.4, -7.5, -7.6, 3.0, -40.0, -29.0], a0, 5)
    assert got.tolist() == [0, 1, 1, 2, 0, 6, 6]
    a1 = [-30, -20, -10, 0, 10, 20, 30]
    assert L.rotation_choice([4.9, 5.0, -5.0, -5.1, 100.0, -100.0], a1, 10).tolist() == [3, 4, 3, 2, 6, 0]


def test_rotation_choice_tie_goes_to_first_choice():
    # class of 5 deg with c=5 is 1, equally far from the classes 0 and 2
    assert L.rotation_choice(5.0, [0, 10], 5).tolist() == 0
    assert L.rotation_choice(5.0, [10, 0], 5).tolist() == 0


def test_euler_matrix_hand_values():
    np.testing.assert_allclose(L.euler_xyz_to_matrix([90.0, 0, 0]), RX90, atol=1e-12)
    np.testing.assert_allclose(L.euler_xyz_to_matrix([0.0, 0, 90]), RZ90, atol=1e-12)
    # intrinsic XYZ: Rx(90) @ Rz(90)
    np.testing.assert_allclose(L.euler_xyz_to_matrix([90.0, 0, 90]), RX90 @ RZ90, atol=1e-12)


def test_relative_euler_hand_values():
    np.testing.assert_allclose(L.relative_euler_xyz(np.eye(3), RX90), [90, 0, 0], atol=1e-9)
    # both frames turned by the same Rz(30): the relative rotation is Rx(-15)
    Ra = L.euler_xyz_to_matrix([0, 0, 30.0])
    Rb = Ra @ L.euler_xyz_to_matrix([-15.0, 0, 0])
    np.testing.assert_allclose(L.relative_euler_xyz(Ra, Rb), [-15, 0, 0], atol=1e-9)
    assert L.rotation_class(L.relative_euler_xyz(Ra, Rb), 5).tolist() == [-3, 0, 0]


def test_relative_euler_roundtrip_batched():
    rng = np.random.default_rng(0)
    angles = np.stack(
        [rng.uniform(-179, 179, 50), rng.uniform(-89, 89, 50), rng.uniform(-179, 179, 50)], axis=-1
    ).reshape(5, 10, 3)
    R = L.euler_xyz_to_matrix(angles)
    assert R.shape == (5, 10, 3, 3)
    np.testing.assert_allclose(L.relative_euler_xyz(np.eye(3), R), angles, atol=1e-8)


def test_relative_euler_gimbal_lock():
    R = L.euler_xyz_to_matrix([10.0, 90.0, 15.0])
    np.testing.assert_allclose(L.relative_euler_xyz(np.eye(3), R), [25, 90, 0], atol=1e-6)
    R = L.euler_xyz_to_matrix([10.0, -90.0, 15.0])
    np.testing.assert_allclose(L.relative_euler_xyz(np.eye(3), R), [-5, -90, 0], atol=1e-6)


# ------------------------------------------------------------------- Eq 5


def test_box_face_centers():
    got = L.box_face_centers([1.0, 2, 3], [0.5, 1, 2], np.eye(3))
    expected = [[1.5, 2, 3], [0.5, 2, 3], [1, 3, 3], [1, 1, 3], [1, 2, 5], [1, 2, 1]]
    np.testing.assert_allclose(got, expected)
    rotated = L.box_face_centers([1.0, 2, 3], [0.5, 1, 2], RZ90)
    np.testing.assert_allclose(rotated[0], [1, 2.5, 3], atol=1e-12)  # box +X now points along world +Y
    np.testing.assert_allclose(rotated[2], [0, 2, 3], atol=1e-12)  # box +Y along world -X


def test_relative_position_label():
    faces = L.box_face_centers(np.zeros(3), np.ones(3), np.eye(3))
    anchors = [[0.0, 0, 0], [1, 1, 0], [0, 0, -2]]  # anchor 0 sits on the centre: excluded
    i, j = L.relative_position_label(np.zeros(3), faces, anchors)
    assert (int(i), int(j)) == (5, 2)  # -Z face with anchor 2, cos = 1


def test_relative_position_tie_is_row_major_first():
    faces = L.box_face_centers(np.zeros(3), np.ones(3), np.eye(3))
    anchors = [[0.0, 2, 0], [3, 0, 0]]  # (+Y, anchor 0) and (+X, anchor 1) both have cos 1
    i, j = L.relative_position_label(np.zeros(3), faces, anchors)
    assert (int(i), int(j)) == (0, 1)


def test_relative_position_all_degenerate_and_batched():
    faces = L.box_face_centers(np.zeros(3), np.ones(3), np.eye(3))
    i, j = L.relative_position_label(np.zeros(3), faces, np.zeros((3, 3)))
    assert (int(i), int(j)) == (-1, -1)
    centers = np.array([[0.0, 0, 0], [10, 0, 0]])
    batch_faces = L.box_face_centers(centers, np.ones((2, 3)), np.broadcast_to(np.eye(3), (2, 3, 3)))
    anchors = np.array([[[0.0, 0, 1], [0, 1, 0]], [[10.0, -1, 0], [10, 0, 0]]])
    i, j = L.relative_position_label(centers, batch_faces, anchors)
    assert i.tolist() == [2, 3] and j.tolist() == [1, 0]


# ------------------------------------------------------------- Eqs 6 and 7


def test_binarize_contacts():
    assert L.binarize_contacts([0.0, 0.5, 1.0, 2.0], 1.0).tolist() == [0, 0, 0, 1]
    assert L.binarize_contacts(np.zeros((2, 17)), 0.0).sum() == 0
    with pytest.raises(ValueError, match="threshold must be >= 0, got -1"):
        L.binarize_contacts([1.0], -1)


def test_jaccard():
    assert L.jaccard([1, 1, 0, 0], [1, 0, 1, 0]) == pytest.approx(1 / 3)
    assert L.jaccard([1, 0, 1], [1, 0, 1]) == 1.0
    assert L.jaccard([0, 0, 0], [0, 0, 0]) == 0.0  # both empty: defined as 0
    assert L.jaccard([0, 0, 0], [1, 0, 0]) == 0.0
    np.testing.assert_allclose(L.jaccard([1, 1, 0], [[1, 1, 0], [0, 0, 1], [1, 0, 0]]), [1, 0, 0.5])


def test_grasp_label_hand_values(bank):
    g = bank.grasp_matrix()
    # {ff_distal, th_distal}: pinch 2/3, extension 2/10, disk 1/6, wrap 1/11
    assert L.grasp_label(contacts("ff_distal", "th_distal"), g) == 2
    for k in range(4):  # every catalogue pattern is recognised as itself
        assert L.grasp_label(g[k], g) == k
    # {palm, ff_proximal, ff_distal}: wrap 3/10, pinch 1/5, disk 1/7, extension 1/12
    batch = np.stack([contacts("palm", "ff_proximal", "ff_distal"), np.zeros(17, np.uint8)])
    assert L.grasp_label(batch, g).tolist() == [0, -1]  # no contact -> -1


def test_grasp_label_edge_cases(bank):
    g = bank.grasp_matrix()
    assert L.grasp_label(contacts("mf_proximal"), g) == -1  # shares no sensor with any pattern
    tie = np.array([[1, 1, 0, 0], [0, 0, 1, 1]], dtype=np.uint8)
    assert L.grasp_label([1, 0, 1, 0], tie) == 0  # 1/3 each -> lowest index
    with pytest.raises(ValueError, match="has 3 sensors, grasp patterns have 17"):
        L.grasp_label([1, 0, 1], g)


# ------------------------------------------------------------------- Eq 8


def test_collinearity_det_hand_values():
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    assert L.collinearity_det(tri) == pytest.approx(1 / 3)  # |cross|^2 / 3 = 1/3
    assert L.collinearity_det(3 * tri) == pytest.approx(27.0)  # |cross|^2 = 81
    assert L.collinearity_det([[0.0, 0, 0], [1, 1, 1], [2, 2, 2]]) == pytest.approx(0.0, abs=1e-12)
    assert L.collinearity_det([[0.0, 0, 0], [1, 2, 3]]) == pytest.approx(0.0, abs=1e-12)


def test_collinear_indicator():
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    line = np.array([[0.0, 0, 0], [1, 1, 1], [2, 2, 2]])
    # sigma(-1/3) = 0.4174: above 0.4, below 0.45
    assert L.collinear_indicator(np.stack([tri, line]), 0.4).tolist() == [1, 1]
    assert L.collinear_indicator(np.stack([tri, line]), 0.45).tolist() == [0, 1]
    assert L.collinear_indicator(3 * tri, 0.4) == 0
    for bad in (0.5, 0.0, 0.7):
        with pytest.raises(ValueError, match=f"tau must be in \\(0, 0.5\\).*got {bad}"):
            L.collinear_indicator(tri, bad)


def test_coplanarity_det_and_indicator():
    assert L.coplanarity_det(np.eye(3)) == pytest.approx(1.0)
    assert L.coplanarity_det(np.diag([2.0, 3, 4])) == pytest.approx(1.0)  # normals rescaled to unit
    four = np.vstack([np.eye(3), [[S2, S2, 0]]])
    assert L.coplanarity_det(four) == pytest.approx(2.0)  # det [[1.5,.5,0],[.5,1.5,0],[0,0,1]]
    flat = np.array([[1.0, 0, 0], [0, 1, 0], [S2, S2, 0]])
    with_zero = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 0]])
    assert L.coplanarity_det(flat) == pytest.approx(0.0, abs=1e-12)
    assert L.coplanarity_det(with_zero) == 0.0
    # sigma(-1) = 0.2689
    assert L.coplanar_indicator(np.stack([np.eye(3), flat, with_zero]), 0.3).tolist() == [0, 1, 1]
    assert L.coplanar_indicator(np.eye(3), 0.25) == 1
    with pytest.raises(ValueError, match="tau must be in"):
        L.coplanar_indicator(flat, 0.5)


# ------------------------------------------------------------------- Eq 9


def test_motion_label_hand_values(bank):
    t = bank.template_matrix()
    assert L.motion_label(velocity(WRJ1=2.0), t) == 0
    assert L.motion_label(velocity(WRJ1=-0.5), t) == 1
    assert L.motion_label(velocity(ARRz=-1.0), t) == 11
    assert L.motion_label(velocity(ARTz=1.0, ARTx=0.1, FFJ3=0.2), t) == 8
    squeeze = velocity(**{f"{f}J{j}": 0.3 for f in ("FF", "MF", "RF", "LF") for j in (1, 2, 3)})
    assert L.motion_label(squeeze, t) == 12
    for k in range(len(t)):  # every template is recognised as itself
        assert L.motion_label(t[k], t) == k


def test_motion_label_edge_cases(bank):
    t = bank.template_matrix()
    assert L.motion_label(np.zeros(30), t) == -1  # no motion
    assert L.motion_label(velocity(WRJ1=1e-12), t) == -1  # below eps
    assert L.motion_label(velocity(WRJ1=1.0, WRJ2=1.0), t) == 0  # cos 1/sqrt2 twice -> lowest
    opening = velocity(FFJ1=-1.0, MFJ2=-1.0)  # against every template: best cos is 0
    assert L.motion_label(opening, t) == -1
    batch = np.stack([velocity(ARTy=-3.0), np.zeros(30), velocity(WRJ2=0.1)])
    assert L.motion_label(batch, t).tolist() == [7, -1, 2]
    with pytest.raises(ValueError, match="has 3 joints, templates have 30"):
        L.motion_label([1.0, 0, 0], t)


def test_motion_choice(bank):
    ttm = bank.template_to_motion
    assert L.motion_choice([0, 1, 8, 11, 12, -1], ttm).tolist() == [0, 0, 4, 5, 6, -1]
    assert L.motion_choice(3, ttm) == 1
    with pytest.raises(ValueError, match="out of range -1..12"):
        L.motion_choice(13, ttm)


# ------------------------------------------------------ tool-object rotation


def test_tool_object_axes_match_catalogue(bank):
    assert L.TOOL_OBJECT_AXES == bank.dim("tool_object_rot").choices


def test_tool_object_rot_label():
    v = [[0, 0, 1], [0, 0, -1], [1, 1, 0], [0, 1, 1], [1, 0.1, 0], [0.2, 1, 0.9], [-1, 0, -1]]
    assert L.tool_object_rot_label(np.array(v, dtype=float)).tolist() == [2, 2, 3, 5, 0, 5, 4]
    assert L.tool_object_rot_label([1.0, 1, 1]) == 3  # X-Y, X-Z, Y-Z tie at 2/sqrt6 -> lowest
    assert L.tool_object_rot_label([0.0, 0, 0]) == -1
