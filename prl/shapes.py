"""Tool and object meshes (pure trimesh) and surface point clouds for the PointNet encoder PN.

Two uses:

* **Scene meshes.**  ``scene_meshes(task, scene_params)`` rebuilds, without the simulator, the tool and
  the object of one randomised scene exactly as the task's ``_load_scene`` builds them (the env files in
  ``envs/tasks`` are the source of truth; the constants copied here are checked against them by a
  ``sim`` test).  Meshes are in the actor's local frame, in metres.
* **Synthetic shapes** for pre-training PN: ``random_shape(category, rng)`` over ``SHAPE_CATEGORIES``.

A mesh is a union of convex watertight parts stored side by side (``trimesh.util.concatenate``, no
boolean engine needed): it is watertight part by part, and ``sample_points`` drops the samples that
fall strictly inside another part, so the point cloud covers only the outer surface of the union.
Parts never share coplanar faces (builders overlap them instead), so no surface is lost.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np
import trimesh

from prl.task_registry import declaration

# --- nominal hammer and nail geometry: the one definition; envs/tasks/hammer.py builds its scene from it
HANDLE_RADIUS = 0.016
"""Nominal handle capsule radius (m)."""
HANDLE_HALF_LENGTH = 0.10
"""Nominal half-length of the handle capsule's cylindrical part (m), along local X."""
HEAD_RADIUS = 0.02
"""Nominal head cylinder radius (m)."""
HEAD_HALF_LENGTH = 0.04
"""Nominal head cylinder half-length (m), along local Y."""
SIZE_SCALE_RANGE = (0.85, 1.15)
"""The env scales handle and head sizes each by an independent factor from this range."""
NAIL_HEAD_RADIUS = 0.025
"""Radius of the nail head disc (m)."""
NAIL_HEAD_THICKNESS = 0.006
"""Thickness of the nail head disc (m)."""
NAIL_SHANK_RADIUS = 0.004
"""Radius of the nail shank (m)."""
NAIL_PROTRUSION = 0.045
"""Height of the nail head's top surface above the board (m)."""
NAIL_SHANK_BELOW_BOARD = 0.02
"""Length of the (visual) shank below the board top (m): the env's shank spans z in [-0.02, protrusion]."""

#: Sections of every cylinder / capsule ring; a multiple of 4 so the bounding box is exact.
_SECTIONS = 32

#: Range of the synthetic shapes' characteristic sizes (m): 2 mm .. 30 cm, the scale of tabletop tools.
SIZE_RANGE_M = (0.002, 0.30)
#: Per-parameter scale range of the "wide" hammer / nail randomisation (beyond the env's +-15 %).
WIDE_SCALE_RANGE = (0.6, 1.4)

_Z_TO_X = trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0])
"""Rotation about Y by +90 deg: trimesh's Z-axis primitives become X-axis ones (SAPIEN's convention)."""
_Z_TO_Y = trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0])
"""Rotation about X by -90 deg: Z-axis primitives become Y-axis ones."""


# ------------------------------------------------------------------ primitives


def _translate(mesh: trimesh.Trimesh, offset: tuple[float, float, float]) -> trimesh.Trimesh:
    mesh.apply_translation(offset)
    return mesh


def _cylinder(radius: float, half_length: float, axis: str = "z") -> trimesh.Trimesh:
    """Cylinder of ``radius`` and ``half_length`` along ``axis`` (``x``, ``y`` or ``z``), centred at the origin."""
    mesh = trimesh.creation.cylinder(radius=1.0, height=2 * half_length / radius, sections=_SECTIONS)
    return _orient(_scaled(mesh, radius), axis)


def _capsule(radius: float, half_length: float, axis: str = "z") -> trimesh.Trimesh:
    """Capsule (SAPIEN convention: ``half_length`` of the cylindrical part) along ``axis``, centred."""
    mesh = trimesh.creation.capsule(height=2 * half_length / radius, radius=1.0, count=[_SECTIONS, _SECTIONS])
    return _orient(_scaled(mesh, radius), axis)


def _scaled(mesh: trimesh.Trimesh, factor: float) -> trimesh.Trimesh:
    """``mesh`` scaled by ``factor``.  Primitives are built at unit radius and then scaled: trimesh merges
    vertices closer than ~1e-8 while building, which would tear millimetre-sized meshes."""
    mesh.apply_scale(factor)
    return mesh


def _orient(mesh: trimesh.Trimesh, axis: str) -> trimesh.Trimesh:
    if axis == "x":
        mesh.apply_transform(_Z_TO_X)
    elif axis == "y":
        mesh.apply_transform(_Z_TO_Y)
    elif axis != "z":
        raise ValueError(f"axis must be 'x', 'y' or 'z', got {axis!r}")
    return mesh


def _union(parts: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Convex watertight parts side by side in one mesh (no boolean: see the module docstring)."""
    return trimesh.util.concatenate(parts)


def _require(params: Mapping[str, float], keys: tuple[str, ...]) -> list[float]:
    """Positive float values of ``keys``; ``ValueError`` naming a missing or non-positive one."""
    values = []
    for key in keys:
        if key not in params:
            raise ValueError(f"scene params lack {key!r}; got keys {sorted(params)}")
        value = float(params[key])
        if not value > 0:
            raise ValueError(f"scene param {key!r} must be > 0, got {params[key]!r}")
        values.append(value)
    return values


# ------------------------------------------------------------------ hammer task


def hammer_tool_mesh(params: Mapping[str, float]) -> trimesh.Trimesh:
    """The hammer of ``envs/tasks/hammer.py`` (``_build_hammer``) in its actor frame (metres).

    A capsule of radius ``handle_radius`` whose cylindrical part has half-length ``handle_half_length``
    along local X, centred at the origin, plus a head cylinder of radius ``head_radius`` and
    half-length ``head_half_length`` with its axis along local Y, centred at
    ``x = handle_half_length + head_radius``.  Bounding box (for ``handle_radius < 2 head_radius``):
    x in ``[-hl - r, hl + 2 hr]``, y in ``[-max(hhl, r), max(hhl, r)]``, z in ``[-max(hr, r), max(hr, r)]``.
    """
    r, hl, hr, hhl = _require(params, ("handle_radius", "handle_half_length", "head_radius", "head_half_length"))
    handle = _capsule(r, hl, "x")
    head = _translate(_cylinder(hr, hhl, "y"), (hl + hr, 0.0, 0.0))
    return _union([handle, head])


def hammer_object_mesh(params: Mapping[str, float]) -> trimesh.Trimesh:
    """The nail of ``envs/tasks/hammer.py`` (``_build_board_and_nail``) in the ``nail_head`` link frame.

    Origin on the board top at the nail axis, Z up: a head disc (radius ``NAIL_HEAD_RADIUS``,
    thickness ``NAIL_HEAD_THICKNESS``) whose top face is at ``z = NAIL_PROTRUSION``, and a shank
    (radius ``NAIL_SHANK_RADIUS``) from ``z = -NAIL_SHANK_BELOW_BOARD`` up into the head.  The env's
    shank reaches the head's top face; here it stops at the head's mid-plane, which is the same union
    solid without coincident faces.  The env does not randomise the nail; the optional keys
    ``nail_head_radius``, ``nail_head_thickness``, ``nail_protrusion`` and ``nail_shank_radius`` in
    ``params`` override the constants (used by the synthetic shapes).
    """
    head_r = float(params.get("nail_head_radius", NAIL_HEAD_RADIUS))
    thick = float(params.get("nail_head_thickness", NAIL_HEAD_THICKNESS))
    protrusion = float(params.get("nail_protrusion", NAIL_PROTRUSION))
    shank_r = float(params.get("nail_shank_radius", NAIL_SHANK_RADIUS))
    for name, value in (("nail_head_radius", head_r), ("nail_head_thickness", thick),
                        ("nail_protrusion", protrusion), ("nail_shank_radius", shank_r)):
        if not value > 0:
            raise ValueError(f"{name} must be > 0, got {value!r}")
    if not thick < protrusion:
        raise ValueError(f"nail_head_thickness {thick!r} must be < nail_protrusion {protrusion!r}")
    head = _translate(_cylinder(head_r, thick / 2, "z"), (0.0, 0.0, protrusion - thick / 2))
    shank_bottom, shank_top = -NAIL_SHANK_BELOW_BOARD, protrusion - thick / 2
    shank = _translate(
        _cylinder(shank_r, (shank_top - shank_bottom) / 2, "z"), (0.0, 0.0, (shank_top + shank_bottom) / 2)
    )
    return _union([head, shank])


# ------------------------------------------------------------------ sweep task
# nominal broom and debris geometry: the one definition; envs/tasks/sweep.py builds its scene from it
BROOM_HANDLE_RADIUS = 0.015
"""Nominal radius of the broom's handle capsule (m)."""
BROOM_HANDLE_HALF_LENGTH = 0.13
"""Nominal half-length of the handle capsule's cylindrical part (m), along the broom's local X."""
BROOM_HEAD_HALF = (0.02, 0.015, 0.07)
"""Nominal half extents (m) of the head block in the broom frame: along the handle (its -X face is the
bottom when the broom stands), thickness (the pushing faces) and width."""
DEBRIS_CUBE_SIZE_RANGE = (0.015, 0.02)
"""Edge length (m) of a debris cube."""
SWEEP_CLEARANCE = 0.003
"""Height (m) of the sweep task's object frame above the table (the head's bottom is planned there)."""


def sweep_tool_mesh(params: Mapping[str, float]) -> trimesh.Trimesh:
    """The broom of ``envs/tasks/sweep.py`` (``_build_broom``) in its actor frame (metres): a capsule of
    radius ``handle_radius`` with cylindrical half-length ``handle_half_length`` along X, centred at the
    origin, and a head box of half extents (``head_half_x``, ``head_half_y``, ``head_half_z``) centred at
    ``x = -(handle_half_length + head_half_x)``. Bounding box: x in ``[-hl - 2 hx, hl + r]``."""
    r, hl, hx, hy, hz = _require(params, ("handle_radius", "handle_half_length", "head_half_x", "head_half_y",
                                          "head_half_z"))
    head = trimesh.creation.box(extents=[2 * hx, 2 * hy, 2 * hz])
    head.apply_translation([-(hl + hx), 0.0, 0.0])
    return _union([_capsule(r, hl, "x"), head])


def sweep_object_mesh(params: Mapping[str, float]) -> trimesh.Trimesh:
    """The debris cubes of ``envs/tasks/sweep.py`` (``_build_debris``) as placed at reset, in the task's
    object frame (origin on the sweep line's centre, ``SWEEP_CLEARANCE`` above the table, axes = world)."""
    (n,) = _require(params, ("n_cubes",))
    origin = np.array([float(params["line_x"]), float(params["line_y"]), SWEEP_CLEARANCE])
    parts = []
    for i in range(int(n)):
        (size,) = _require(params, (f"cube{i}_size",))
        cube = trimesh.creation.box(extents=[size] * 3)
        cube.apply_transform(trimesh.transformations.rotation_matrix(float(params[f"cube{i}_yaw"]), [0, 0, 1]))
        cube.apply_translation(np.array([params[f"cube{i}_x"], params[f"cube{i}_y"], size / 2]) - origin)
        parts.append(cube)
    return _union(parts)


# ------------------------------------------------------------------ unscrew task
CAP_TOP_PROUD = 0.001
"""The cap's smooth top disc stands this far above its side (envs/tasks/unscrew.py)."""
CAP_CENTER_HEIGHT = 0.09
"""Height (m) of the cap's centre above the table."""
NECK_RADIUS = 0.012
"""Radius (m) of the bottle's neck under the cap."""


def unscrew_tool_mesh(params: Mapping[str, float]) -> trimesh.Trimesh:
    """The cap of ``envs/tasks/unscrew.py`` in its link frame: a cylinder of radius ``cap_radius`` and
    half-height ``cap_half_height`` along local Y, and the smooth top disc (3 mm narrower) on its +Y face."""
    r, hh = _require(params, ("cap_radius", "cap_half_height"))
    top = _translate(_cylinder(r - 0.003, CAP_TOP_PROUD / 2 + 0.0005, "y"), (0.0, hh + CAP_TOP_PROUD / 2 - 0.0005, 0.0))
    return _union([_cylinder(r, hh, "y"), top])


def unscrew_object_mesh(params: Mapping[str, float]) -> trimesh.Trimesh:
    """The bottle of ``envs/tasks/unscrew.py`` (body and neck) in the task's object frame: origin at the cap's
    seat on the neck, Z up along the bottle's axis."""
    rb, hb, hh = _require(params, ("body_radius", "body_height", "cap_half_height"))
    seat = CAP_CENTER_HEIGHT - hh
    body = _translate(_cylinder(rb, hb / 2, "z"), (0.0, 0.0, hb / 2 - seat))
    neck_half = (seat - hb) / 2 + 0.002
    neck = _translate(_cylinder(NECK_RADIUS, neck_half, "z"), (0.0, 0.0, hb + (seat - hb) / 2 - seat))
    return _union([body, neck])


# ------------------------------------------------------------------ tweeze task
TWEEZERS_ARM_HEIGHT = 0.012
"""Height (m) of each tweezers arm standing on edge (its extent along the tweezers' Z, vertical at rest)."""
TWEEZERS_ARM_THICKNESS = 0.003
"""Thickness (m) of each arm along the closing direction."""
TWEEZERS_BUTT_LENGTH = 0.012
"""Length (m) of the block behind the hinge that joins the arms."""
TWEEZERS_LINK_IN_FRAME = np.diag([-1.0, 1.0, -1.0])
"""The tweezers' root link frame in their own frame (origin at the hinge, X along the arms towards the tips, Y
along the height, Z across from arm a to arm b): half a turn about Y. The link frame is the tool frame the
executor grasps in (palm frame = T_gv frame turned by a0, a1), so its X, the palm's thumb side, points towards
the butt, and the palm's little-finger side and the extended fingers lie towards the tips but clear of them."""


def tweezers_arm_angle(arm_length: float, tip_gap: float) -> float:
    """Half opening angle (rad) of tweezers whose arms' inner faces run from the hinge to tips ``tip_gap`` apart."""
    return float(np.arcsin(tip_gap / (2 * arm_length)))


def tweeze_tool_mesh(params: Mapping[str, float]) -> trimesh.Trimesh:
    """The open tweezers of ``envs/tasks/tweeze.py`` in their root link's frame (``TWEEZERS_LINK_IN_FRAME``):
    origin at the hinge, the arms along -X, standing ``arm_height`` tall along Y and opening symmetrically
    along Z, and the joining block behind the hinge (+X)."""
    length, gap = _require(params, ("arm_length", "tip_gap"))
    height = float(params.get("arm_height", TWEEZERS_ARM_HEIGHT))
    thick = float(params.get("arm_thickness", TWEEZERS_ARM_THICKNESS))
    angle = tweezers_arm_angle(length, gap)
    parts = [_translate(trimesh.creation.box(extents=[TWEEZERS_BUTT_LENGTH, height, 4 * thick]),
                        (-TWEEZERS_BUTT_LENGTH / 2, 0.0, 0.0))]
    for side in (1.0, -1.0):
        arm = trimesh.creation.box(extents=[length, height, thick])
        arm.apply_translation([length / 2, 0.0, side * thick / 2])
        arm.apply_transform(trimesh.transformations.rotation_matrix(-side * angle, [0, 1, 0]))
        parts.append(arm)
    mesh = _union(parts)
    to_link = np.eye(4)
    to_link[:3, :3] = TWEEZERS_LINK_IN_FRAME.T
    mesh.apply_transform(to_link)
    return mesh


def tweeze_object_mesh(params: Mapping[str, float]) -> trimesh.Trimesh:
    """The cube of ``envs/tasks/tweeze.py`` in the task's object frame (origin at its bottom face's centre, Z up)."""
    (size,) = _require(params, ("cube_size",))
    return _translate(trimesh.creation.box(extents=[size] * 3), (0.0, 0.0, size / 2))


MeshBuilder = Callable[[Mapping[str, float]], trimesh.Trimesh]

def scene_meshes(task: str, scene_params: Mapping[str, float]) -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
    """``(tool_mesh, object_mesh)`` of one scene of ``task`` from the env's ``scene_params``, built by the mesh
    builders its environment class declares (``prl.task_registry``; a variant inherits its task's: its scenes are
    built from the same parameters, a variant moves or resizes them and the poses are in x_manip). ValueError naming
    a task that declares none; KeyError (``prl.task_registry.declaration``) for one not declared in this process."""
    meshes = declaration(task).meshes
    if meshes is None:
        raise ValueError(f"task {task!r} declares no mesh builders (its class's tool_mesh and object_mesh)")
    tool_builder, object_builder = meshes
    return tool_builder(scene_params), object_builder(scene_params)


# ------------------------------------------------------------------ point sampling


_Part = tuple[np.ndarray, np.ndarray, np.ndarray]


def _convex_parts(mesh: trimesh.Trimesh) -> tuple[np.ndarray, list[_Part | None]]:
    """``(face_part (F,), parts)``: the connected part of each face, and per part its bounds and face
    planes ``(bounds (2, 3), normals (K, 3), offsets (K,))`` (a point ``p`` is inside when
    ``normals @ p < offsets`` for all of them; duplicate planes merged), or ``None`` for a part that is
    not convex and watertight.
    ``parts`` is empty for a single-part mesh (nothing can hide inside another part)."""
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    parts: list[_Part | None] = []
    if labels.max(initial=0) == 0:
        return labels, parts
    for k in range(labels.max() + 1):
        part = mesh.submesh([np.flatnonzero(labels == k)], append=True)
        if part.is_watertight and part.is_convex:
            normals = part.face_normals
            planes = np.column_stack([normals, np.einsum("ij,ij->i", normals, part.triangles[:, 0])])
            planes = np.unique(np.round(planes, 9), axis=0)
            parts.append((part.bounds, planes[:, :3], planes[:, 3]))
        else:
            parts.append(None)
    return labels, parts


def _hidden(points: np.ndarray, own: np.ndarray, parts: list[_Part | None], tol: float) -> np.ndarray:
    """Mask of ``points`` (of parts ``own``) lying deeper than ``tol`` inside another convex part."""
    hidden = np.zeros(len(points), dtype=bool)
    for k, part in enumerate(parts):
        if part is None:
            continue
        bounds, normals, offsets = part
        in_box = np.all((points > bounds[0] + tol) & (points < bounds[1] - tol), axis=1)
        test = np.flatnonzero((own != k) & in_box)
        if len(test):
            hidden[test] |= np.all(points[test] @ normals.T - offsets < -tol, axis=1)
    return hidden


def sample_points(mesh: trimesh.Trimesh, n: int, seed: int) -> np.ndarray:
    """``n`` points (float32 ``(n, 3)``) sampled uniformly on the outer surface of ``mesh``.

    Area-weighted samples (``trimesh.sample.sample_surface`` with a generator seeded by ``seed``), minus
    those strictly inside another convex part of the mesh (see the module docstring).  The cloud is
    translated so that the mesh's bounding-box centre is the origin and is NOT scaled: the encoder sees
    the object's size.  Deterministic for a given ``(mesh, n, seed)``.
    """
    if not isinstance(n, int | np.integer) or isinstance(n, bool) or n <= 0:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    if len(mesh.faces) == 0 or not mesh.area > 0:
        raise ValueError(f"mesh has no surface to sample (faces={len(mesh.faces)}, area={mesh.area!r})")
    rng = np.random.default_rng(seed)
    labels, parts = _convex_parts(mesh)
    tol = 1e-7 * max(float(mesh.scale), 1e-12)
    kept: list[np.ndarray] = []
    total = 0
    for _ in range(100):
        points, faces = trimesh.sample.sample_surface(mesh, 2 * n if parts else n, seed=rng)
        if parts:
            points = points[~_hidden(points, labels[faces], parts, tol)]
        kept.append(points)
        total += len(points)
        if total >= n:
            break
    else:
        raise ValueError(f"could not sample {n} outer-surface points from a mesh of area {mesh.area!r}")
    points = np.concatenate(kept)[:n]
    center = mesh.bounds.mean(axis=0)
    return (points - center).astype(np.float32)


# ------------------------------------------------------------------ synthetic shapes

#: Categories of ``random_shape``, in label order (the PointNet's class index).
SHAPE_CATEGORIES: tuple[str, ...] = (
    "box", "cylinder", "capsule", "sphere", "cone", "hammer", "nail", "tweezers", "broom", "debris", "bottle",
)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A size drawn log-uniformly in ``[lo, hi]`` (every order of magnitude equally likely)."""
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _scale_factors(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` size factors: half the time the env's joint +-15 % (one factor), else ``WIDE_SCALE_RANGE`` each."""
    if rng.random() < 0.5:
        return np.full(n, rng.uniform(*SIZE_SCALE_RANGE))
    return rng.uniform(*WIDE_SCALE_RANGE, size=n)


def _random_hammer(rng: np.random.Generator) -> trimesh.Trimesh:
    handle = _scale_factors(rng, 2)
    head = _scale_factors(rng, 2)
    params = {
        "handle_radius": HANDLE_RADIUS * handle[0],
        "handle_half_length": HANDLE_HALF_LENGTH * handle[1],
        "head_radius": HEAD_RADIUS * head[0],
        "head_half_length": HEAD_HALF_LENGTH * head[1],
    }
    return hammer_tool_mesh(params)


def _random_nail(rng: np.random.Generator) -> trimesh.Trimesh:
    s = _scale_factors(rng, 4)
    params = {
        "nail_head_radius": NAIL_HEAD_RADIUS * s[0],
        "nail_head_thickness": NAIL_HEAD_THICKNESS * s[1],
        "nail_protrusion": NAIL_PROTRUSION * s[2],
        "nail_shank_radius": NAIL_SHANK_RADIUS * s[3],
    }
    return hammer_object_mesh(params)


def _random_tweezers(rng: np.random.Generator) -> trimesh.Trimesh:
    """The tweeze task's tweezers (``tweeze_tool_mesh``) with arms 2 .. 20 cm long, 2 .. 6 mm thick and
    4 .. 20 mm high, tips 2 mm .. 5 cm apart."""
    length = _log_uniform(rng, 0.02, 0.20)
    return tweeze_tool_mesh({"arm_length": length, "tip_gap": min(_log_uniform(rng, 0.002, 0.05), length),
                             "arm_thickness": _log_uniform(rng, 0.002, 0.006),
                             "arm_height": _log_uniform(rng, 0.004, 0.020)})


def _random_broom(rng: np.random.Generator) -> trimesh.Trimesh:
    handle = rng.uniform(0.7, 1.2, size=2)  # the nominal broom is 31 cm long: longer ones leave SIZE_RANGE_M
    head = _scale_factors(rng, 3)
    return sweep_tool_mesh({
        "handle_radius": BROOM_HANDLE_RADIUS * handle[0], "handle_half_length": BROOM_HANDLE_HALF_LENGTH * handle[1],
        **{f"head_half_{axis}": BROOM_HEAD_HALF[i] * head[i] for i, axis in enumerate("xyz")},
    })


def _random_debris(rng: np.random.Generator) -> trimesh.Trimesh:
    """3 .. 10 cubes of 1 .. 3 cm, each turned about Z, on a 4 x 4 grid of 3.5 cm slots (they never overlap)."""
    n = int(rng.integers(3, 11))
    params: dict[str, float] = {"n_cubes": n, "line_x": 0.0, "line_y": 0.0}
    for i, slot in enumerate(rng.permutation(16)[:n]):
        row, col = divmod(int(slot), 4)
        size = rng.uniform(0.01, 0.03)
        params |= {f"cube{i}_size": size, f"cube{i}_yaw": rng.uniform(-np.pi / 4, np.pi / 4),
                   f"cube{i}_x": -0.035 * (row + 0.5), f"cube{i}_y": 0.035 * (col - 1.5)}
    return sweep_object_mesh(params)


def _random_bottle(rng: np.random.Generator) -> trimesh.Trimesh:
    """The unscrew task's bottle (body and neck) with body radius 1.5 .. 5 cm and height 2 .. 7 cm."""
    return unscrew_object_mesh({"body_radius": rng.uniform(0.015, 0.05), "body_height": rng.uniform(0.02, 0.07),
                                "cap_half_height": rng.uniform(0.008, 0.015)})


def random_shape(category: str, rng: np.random.Generator) -> trimesh.Trimesh:
    """A random mesh of ``category`` (one of ``SHAPE_CATEGORIES``), in metres, in a canonical frame.

    Sizes (log-uniform unless said otherwise), within ``SIZE_RANGE_M`` = 2 mm .. 30 cm:

    * ``box``: each extent in [2 mm, 30 cm];
    * ``cylinder`` / ``cone``: radius in [1 mm, 10 cm], length in [2 mm, 30 cm];
    * ``capsule``: radius in [1 mm, 5 cm], cylindrical length in [2 mm, 20 cm];
    * ``sphere``: radius in [1 mm, 15 cm];
    * ``hammer`` / ``nail``: the env's builders with the nominal sizes scaled, half the time by one
      factor in the env's ``SIZE_SCALE_RANGE`` (+-15 %), else by independent factors per parameter in
      ``WIDE_SCALE_RANGE`` (0.6 .. 1.4, unseen proportions; hammers then reach ~36 cm);
    * ``tweezers``: the tweeze task's tweezers, arms 2 .. 20 cm long, 2 .. 6 mm thick, 4 .. 20 mm high,
      tips 2 mm .. 5 cm apart;
    * ``broom``: the sweep task's broom, its head scaled like ``hammer``, its handle by 0.7 .. 1.2;
    * ``debris``: 3 .. 10 cubes of 1 .. 3 cm in a patch (the sweep task's object);
    * ``bottle``: the unscrew task's bottle (body and neck), body radius 1.5 .. 5 cm, height 2 .. 7 cm.
    """
    lo, hi = SIZE_RANGE_M
    if category == "box":
        return trimesh.creation.box(extents=[_log_uniform(rng, lo, hi) for _ in range(3)])
    if category == "cylinder":
        return _cylinder(_log_uniform(rng, lo / 2, 0.10), _log_uniform(rng, lo, hi) / 2)
    if category == "capsule":
        return _capsule(_log_uniform(rng, lo / 2, 0.05), _log_uniform(rng, lo, 0.20) / 2)
    if category == "sphere":
        return _scaled(trimesh.creation.icosphere(subdivisions=3), _log_uniform(rng, lo / 2, hi / 2))
    if category == "cone":
        radius = _log_uniform(rng, lo / 2, 0.10)
        cone = trimesh.creation.cone(radius=1.0, height=_log_uniform(rng, lo, hi) / radius, sections=_SECTIONS)
        return _scaled(cone, radius)
    if category == "hammer":
        return _random_hammer(rng)
    if category == "nail":
        return _random_nail(rng)
    if category == "tweezers":
        return _random_tweezers(rng)
    if category == "broom":
        return _random_broom(rng)
    if category == "debris":
        return _random_debris(rng)
    if category == "bottle":
        return _random_bottle(rng)
    raise ValueError(f"unknown shape category {category!r}; known: {', '.join(SHAPE_CATEGORIES)}")
