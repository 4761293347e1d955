"""Tool / object meshes rebuilt without the simulator, and their surface point clouds (prl.shapes)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from prl import shapes as S

#: A hammer away from the nominal sizes, so a swapped parameter shows.
PARAMS = {"handle_radius": 0.018, "handle_half_length": 0.09, "head_radius": 0.017, "head_half_length": 0.045}


def hammer_sdf(p: np.ndarray, params: dict[str, float]) -> np.ndarray:
    """Analytic signed distance (m) of the hammer union: capsule along X, head cylinder along Y."""
    r, hl = params["handle_radius"], params["handle_half_length"]
    hr, hhl = params["head_radius"], params["head_half_length"]
    axis = np.stack([np.clip(p[:, 0], -hl, hl), np.zeros(len(p)), np.zeros(len(p))], axis=1)
    capsule = np.linalg.norm(p - axis, axis=1) - r
    radial = np.hypot(p[:, 0] - (hl + hr), p[:, 2]) - hr
    along = np.abs(p[:, 1]) - hhl
    outside = np.hypot(np.maximum(radial, 0), np.maximum(along, 0))
    cylinder = outside + np.minimum(np.maximum(radial, along), 0)
    return np.minimum(capsule, cylinder)


def test_hammer_bounding_box_matches_hand_computed_extents():
    r, hl, hr, hhl = (PARAMS[k] for k in ("handle_radius", "handle_half_length", "head_radius", "head_half_length"))
    mesh = S.hammer_tool_mesh(PARAMS)
    # x: butt of the capsule at -(hl + r); head cylinder centred at hl + hr reaches hl + 2 hr.
    # y: head half-length 0.045 > handle radius; z: handle radius 0.018 > head radius 0.017.
    expected = np.array([[-hl - r, -hhl, -r], [hl + 2 * hr, hhl, r]])
    np.testing.assert_allclose(mesh.bounds, expected, atol=1e-9)
    assert mesh.extents[0] == pytest.approx(2 * hl + r + 2 * hr, abs=1e-9)  # 0.232 m


def test_hammer_mesh_is_watertight_with_the_parts_volume():
    mesh = S.hammer_tool_mesh(PARAMS)
    assert mesh.is_watertight
    r, hl, hr, hhl = (PARAMS[k] for k in ("handle_radius", "handle_half_length", "head_radius", "head_half_length"))
    # parts are stored side by side (no boolean), so the volume is the sum of the two solids
    analytic = np.pi * r**2 * 2 * hl + 4 / 3 * np.pi * r**3 + np.pi * hr**2 * 2 * hhl
    assert mesh.volume > 0
    assert mesh.volume == pytest.approx(analytic, rel=0.02)


def test_nail_mesh_matches_env_geometry():
    mesh = S.hammer_object_mesh({})
    expected = np.array([[-S.NAIL_HEAD_RADIUS, -S.NAIL_HEAD_RADIUS, -S.NAIL_SHANK_BELOW_BOARD],
                         [S.NAIL_HEAD_RADIUS, S.NAIL_HEAD_RADIUS, S.NAIL_PROTRUSION]])
    np.testing.assert_allclose(mesh.bounds, expected, atol=1e-9)
    assert mesh.is_watertight and mesh.volume > 0
    bigger = S.hammer_object_mesh({"nail_head_radius": 0.03})
    assert bigger.extents[0] == pytest.approx(0.06, abs=1e-9)


def test_scene_meshes_reads_the_task_class_builders_and_names_an_unknown_task():
    import envs.tasks  # noqa: F401  (heavy: the simulator; its task classes declare their mesh builders)

    tool, obj = S.scene_meshes("hammer", PARAMS)
    np.testing.assert_allclose(tool.bounds, S.hammer_tool_mesh(PARAMS).bounds)
    np.testing.assert_allclose(obj.bounds, S.hammer_object_mesh(PARAMS).bounds)
    with pytest.raises(KeyError, match="'screwdriver' is not declared"):
        S.scene_meshes("screwdriver", PARAMS)
    variant_tool, _ = S.scene_meshes("hammer_mixed", PARAMS)  # a variant without builders: its task's
    np.testing.assert_allclose(variant_tool.bounds, tool.bounds)
    with pytest.raises(ValueError, match="'head_radius'"):
        S.hammer_tool_mesh({k: v for k, v in PARAMS.items() if k != "head_radius"})


def test_sample_points_deterministic_and_seed_dependent():
    mesh = S.hammer_tool_mesh(PARAMS)
    a = S.sample_points(mesh, 300, seed=3)
    b = S.sample_points(mesh, 300, seed=3)
    c = S.sample_points(mesh, 300, seed=4)
    assert a.shape == (300, 3) and a.dtype == np.float32
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_sample_points_cover_only_the_outer_surface_centred_not_scaled():
    mesh = S.hammer_tool_mesh(PARAMS)
    pts = S.sample_points(mesh, 4000, seed=0)
    world = pts.astype(float) + mesh.bounds.mean(axis=0)
    sdf = hammer_sdf(world, PARAMS)
    # facets of the 32-gon rings sit inside the true surface by ~r (1 - cos(pi / 32)) ~ 0.1 mm here
    assert np.all(np.abs(sdf) < 2e-4), f"worst |sdf| {np.abs(sdf).max():.2e} m"
    # the check can fail: plain surface sampling also hits the handle's end inside the head
    raw, _ = trimesh.sample.sample_surface(mesh, 4000, seed=0)
    assert np.sum(hammer_sdf(raw, PARAMS) < -2e-4) > 50
    # centred on the bounding-box centre, at the mesh's own size
    np.testing.assert_allclose(pts.max(0) + pts.min(0), 0.0, atol=2e-3)
    np.testing.assert_allclose(pts.max(0) - pts.min(0), mesh.extents, rtol=0.03)


def test_sample_points_rejects_bad_count():
    mesh = S.hammer_tool_mesh(PARAMS)
    with pytest.raises(ValueError, match="0"):
        S.sample_points(mesh, 0, seed=0)


@pytest.mark.parametrize("category", S.SHAPE_CATEGORIES)
def test_random_shapes_watertight_in_size_range_and_deterministic(category):
    meshes = [S.random_shape(category, np.random.default_rng(seed)) for seed in range(12)]
    again = S.random_shape(category, np.random.default_rng(0))
    np.testing.assert_allclose(again.vertices, meshes[0].vertices)
    for mesh in meshes:
        assert mesh.is_watertight and mesh.volume > 0
        assert mesh.extents.max() >= S.SIZE_RANGE_M[0] and mesh.extents.max() <= 0.40
        pts = S.sample_points(mesh, 64, seed=1)
        assert pts.shape == (64, 3) and np.all(np.isfinite(pts))
    assert len({round(float(m.extents.max()), 6) for m in meshes}) > 1, "sizes are not randomised"


def test_shape_family_has_the_scene_categories_and_rejects_unknown():
    assert len(S.SHAPE_CATEGORIES) >= 6
    assert {"hammer", "nail"} <= set(S.SHAPE_CATEGORIES)
    with pytest.raises(ValueError, match="'teapot'"):
        S.random_shape("teapot", np.random.default_rng(0))


@pytest.mark.sim
def test_copied_constants_equal_the_env_constants():
    hammer = pytest.importorskip("envs.tasks.hammer")
    for name in ("HANDLE_RADIUS", "HANDLE_HALF_LENGTH", "HEAD_RADIUS", "HEAD_HALF_LENGTH", "SIZE_SCALE_RANGE",
                 "NAIL_HEAD_RADIUS", "NAIL_HEAD_THICKNESS", "NAIL_SHANK_RADIUS", "NAIL_PROTRUSION"):
        assert getattr(S, name) == getattr(hammer, name), name
