"""Shared base class of the four PRL tool-use tasks (hammer, sweep, unscrew, tweeze).

World frame: Z up, the table top is the plane z = 0, metres, kilograms, seconds.

Every task rebuilds its scene on every reset (``reconfiguration_freq=1``): tool and
object *sizes* are domain-randomised and PhysX shapes cannot be resized after they
are built, so ``_load_scene`` samples all of an episode's random values from the
episode's seeded generator (``self._batched_episode_rng[0]``, seeded by ManiSkill
from ``reset(seed=...)`` just before ``_load_scene``) and stores them in
``self.scene_params``. ``_initialize_episode`` then places the bodies from those
stored values without drawing new numbers, so the same seed gives the same scene.

The plan executor (``envs/executor.py``) relies on the public API below:
``task_name``, ``tool``, ``tool_gv_local``/``tool_fv_local``, ``tool_gv_world()``,
``tool_fv_world()``, ``object_frame_world()``, ``scene_params`` and ``evaluate()``.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import sapien
import torch
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.utils.structs import Actor
from mani_skill.utils.structs.types import DefaultMaterialsConfig, SceneConfig, SimConfig
from sapien import physx

from envs.reach import REACH_MARGIN, HandReach, moving_bodies
from prl.constants import SIM_FREQ
from prl.geometry import rot_z
from prl.shapes import MeshBuilder
from prl.stages import StageSpec
from prl.task_registry import TaskDecl, declare

Box = tuple[np.ndarray, np.ndarray]
"""An axis-aligned box in some frame: (center (3,), half_extents (3,)), metres."""

WorldBox = tuple[np.ndarray, np.ndarray, np.ndarray]
"""An oriented box in the world frame: (center (3,), half_extents (3,), R (3, 3)), R's columns = box axes."""

CONTROL_FREQ = 50
"""Control steps per second of ``env.step``."""
SOLVER_POSITION_ITERATIONS = 20
"""PhysX position iterations per step (>= 20 advised for stable multi-finger grasps). With ``SIM_FREQ`` =
250 Hz: on 210 fixed hammer (scene, plan) pairs (expert, prior and uniform plans) this agreed with a
converged reference (1000 Hz, 50 iterations, same 3 s) on success in 195, as often as the former
500 Hz / 25 did (195), at half its cost per attempt; no blow-up, the same tool slip in the hand during the
carry (median 0.4 mm). 250 Hz / 12 and 200 Hz / 10 were cheaper and agreed less (191, 192)."""

DEFAULT_ENV_KWARGS: dict[str, Any] = {
    "num_envs": 1,
    "sim_backend": "physx_cpu",
    "render_mode": None,
    "obs_mode": "state_dict",
    "robot_uids": "prl_hand",
}
"""Defaults for ``envs.tasks.make_env`` (and the grasp probe's): one CPU-simulated scene, no rendering, the PRL hand."""


def physics_sim_config(sim_freq: int = SIM_FREQ, position_iterations: int = SOLVER_POSITION_ITERATIONS) -> SimConfig:
    """ManiSkill's ``SimConfig`` of a PRL task scene at ``sim_freq`` Hz with that many PhysX position
    iterations (the pipeline's own settings by default; others for the fidelity study of
    ``bench/bench_physics.py``)."""
    if sim_freq % CONTROL_FREQ:
        raise ValueError(f"sim_freq must be a multiple of the control rate {CONTROL_FREQ} Hz, got {sim_freq!r}")
    return SimConfig(
        sim_freq=int(sim_freq),
        control_freq=CONTROL_FREQ,
        scene_config=SceneConfig(solver_position_iterations=int(position_iterations), solver_velocity_iterations=1),
        default_materials_config=DefaultMaterialsConfig(
            static_friction=TABLE_FRICTION, dynamic_friction=TABLE_FRICTION, restitution=0.0
        ),
    )

TABLE_HALF_SIZE = (0.6, 0.6, 0.375)
"""Half extents of the static table box; its top is the plane z = 0."""
TABLE_FRICTION = 0.8
"""Static = dynamic friction of the table and the other static props."""


def pose_to_numpy(raw_pose: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Convert a ManiSkill raw pose (1, 7) [x, y, z, qw, qx, qy, qz] to (position (3,), rotation matrix (3, 3))."""
    values = raw_pose.detach().cpu().numpy().reshape(-1, 7)[0].astype(np.float64)
    matrix = sapien.Pose(values[:3], values[3:]).to_transformation_matrix()
    return values[:3].copy(), np.asarray(matrix[:3, :3], dtype=np.float64)


def yaw_matrix(yaw: float) -> np.ndarray:
    """Rotation matrix (3, 3) about world Z by ``yaw`` radians."""
    return rot_z(yaw)


def pose_from_matrix(position: np.ndarray, rotation: np.ndarray) -> sapien.Pose:
    """A ``sapien.Pose`` from a position (3,) and a rotation matrix (3, 3)."""
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = position
    return sapien.Pose(transform)


class PRLTaskEnv(BaseEnv):
    """Base of the PRL tasks: simulation settings, the table, and the executor-facing API.

    Subclasses implement ``_load_scene`` (call ``_build_table`` and sample everything
    random from ``_scene_rng()``, set ``self.tool``, ``tool_gv_local``, ``tool_fv_local``
    and ``scene_params``), ``_initialize_episode`` (call ``_reset_hand``),
    ``object_frame_world`` and ``evaluate``. Only the CPU backend with one environment
    is supported (the scene is rebuilt on every reset).
    """

    SUPPORTED_ROBOTS: ClassVar[list[str]] = ["prl_hand"]
    SUPPORTED_REWARD_MODES = ("dense", "normalized_dense", "sparse", "none")

    task_name: str = ""
    """Short task name used across the pipeline ("hammer", "sweep", ...)."""
    pipeline_task: ClassVar[bool] = True
    """Whether the pipeline lists this environment as a task (``envs.tasks.TASK_ENV_IDS``); False for probes."""
    measure_key: str = ""
    """Key of ``evaluate()`` holding the task's measured quantity (the paper's reward)."""
    measure_unit: ClassVar[str] = ""
    """Unit of the measure (``"cm"``, ``"degrees"``, ``"cubes"``): the report names it beside the rewards."""
    tool_mesh: ClassVar[MeshBuilder | None] = None
    """The tool's mesh in its actor frame from ``scene_params`` (a ``staticmethod``; ``prl.shapes.scene_meshes``
    samples the PointNet's points on it). A variant inherits its task's."""
    object_mesh: ClassVar[MeshBuilder | None] = None
    """The object's mesh in the task's object frame from ``scene_params`` (a ``staticmethod``)."""
    evidence: ClassVar[tuple[str, ...]] = ()
    """Keys of ``evaluate()`` the red team shows beside each success: how the measure came about."""
    catalogue_entry: ClassVar[Mapping[str, Any] | None] = None
    """The task's PLB entry (``{"texts": [...], "prior": [[...], ...]}``) for a task kept outside the repository's
    catalogue; None reads ``assets/plb.yaml`` (or, for a variant without an entry, its task's)."""
    expert_plan: tuple[int, ...] = ()
    """A hand-designed plan that should succeed on most randomised scenes (a reference, not a label)."""
    unacted_dims: ClassVar[tuple[str, ...]] = ()
    """Representation-Space dimensions (``prl.plb`` names) this task's stages never act on: without a place stage
    the executor never reads a5 (``tool_object_rot``). Their labels read what the scene gives whatever the plan,
    the expert commands that value, and label agreement is reported over the other (acted) dimensions."""
    stages: ClassVar[StageSpec]
    """The executor stages this task runs, their time shares, where T_fv meets the object and what follows
    the motion (``prl.stages.StageSpec``): data, so the executor needs no per-task branch."""
    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Declare a task class in ``prl.task_registry`` as soon as it is defined (its environment id follows when
        ``envs.tasks`` looks its registration up), so that importing a task's module is enough. Only a class that
        names itself (``task_name`` in its own body) is a task: a subclass that keeps its parent's name is not."""
        super().__init_subclass__(**kwargs)
        if cls.pipeline_task and cls.__dict__.get("task_name"):
            declare(cls.declaration(""))

    @classmethod
    def declaration(cls, env_id: str) -> TaskDecl:
        """This task class as the registry declares it: its name, module file, base task and the class attributes
        the pipeline reads. A class is a variant of the ancestor task class whose name its own extends
        (``hammer_mixed`` of ``hammer``); a subclass with a name of its own (no underscore) is a base task that
        reuses its parent's scene."""
        base = next((c.task_name for c in cls.__mro__[1:] if isinstance(c, type) and issubclass(c, PRLTaskEnv)
                     and c.task_name and cls.task_name.startswith(f"{c.task_name}_")), "")
        meshes = (cls.tool_mesh, cls.object_mesh) if cls.tool_mesh and cls.object_mesh else None
        return TaskDecl(name=cls.task_name, env_id=env_id, module_file=Path(inspect.getfile(cls)).resolve(),
                        base=base, meshes=meshes, evidence=tuple(cls.evidence), measure_unit=cls.measure_unit,
                        catalogue_entry=cls.catalogue_entry)

    tool: Actor
    """The tool: one dynamic rigid actor held by contact and friction only."""
    tool_gv_local: Box
    """Graspable volume T_gv as (center, half_extents) in the tool's actor frame, metres."""
    tool_fv_local: Box
    """Functional volume T_fv as (center, half_extents) in the tool's actor frame, metres."""
    scene_params: dict[str, float]
    """The randomised values of the current episode as plain floats (SI units)."""

    def __init__(self, *args: Any, robot_uids: str = "prl_hand", randomization: float = 1.0, **kwargs: Any) -> None:
        if isinstance(randomization, bool) or not isinstance(randomization, (int, float)) or not randomization > 0:
            raise ValueError(f"randomization must be a positive number, got {randomization!r}")
        self.randomization = float(randomization)
        kwargs.setdefault("reconfiguration_freq", 1)
        if kwargs["reconfiguration_freq"] != 1:
            raise ValueError(
                f"PRL tasks rebuild their randomised scene on every reset; reconfiguration_freq must be 1, "
                f"got {kwargs['reconfiguration_freq']!r}"
            )
        self.scene_params = {}
        super().__init__(*args, robot_uids=robot_uids, **kwargs)

    @property
    def _default_sim_config(self) -> SimConfig:
        return physics_sim_config()

    # ------------------------------------------------------------------ scene helpers
    def _uniform(self, rng: np.random.RandomState, low: float, high: float) -> float:
        """A draw from [low, high] with the half-width scaled by ``randomization`` about the centre.

        ``randomization`` = 1 gives the training ranges; e.g. 2 doubles every range's half-width (a
        harder split with values the training scenes never had). The same seed maps to the same
        relative position inside the range, whatever the scale.

        A range of positive values (``low > 0``: sizes, masses, frictions, forces) stays positive: a
        widened lower end stops at ``low / randomization`` (at scale 4, a 0.2-0.45 kg range becomes
        0.05-0.825 kg, not -0.175-0.825 kg), so every scale builds a physical scene.
        """
        centre, half = (low + high) / 2, (high - low) / 2 * self.randomization
        lower = centre - half
        if low > 0 and self.randomization > 1:
            lower = max(lower, low / self.randomization)
        return float(rng.uniform(lower, centre + half))

    def _scene_rng(self) -> np.random.RandomState:
        """The episode's seeded generator (ManiSkill's per-episode RNG of environment 0)."""
        return self._batched_episode_rng[0]

    def _load_agent(self, options: dict, initial_agent_poses: Any = None, build_separate: bool = False) -> None:
        """Load the hand with its fixed root at the world origin (the arm joints carry it from there)."""
        super()._load_agent(options, sapien.Pose() if initial_agent_poses is None else initial_agent_poses,
                            build_separate)
        # the hand's PhysX entities -> link names, built once per (re)built scene: the per-frame contact watches
        # ask it every frame, and building it took 16 us against 0.4 us for the contact scan at rest
        self._hand_link_names = {} if self.agent is None else {
            link._objs[0].entity: link.name for link in self.agent.robot.get_links()}

    def _build_table(self) -> None:
        """Build the static table (top at z = 0) and a floor plane under it."""
        hx, hy, hz = TABLE_HALF_SIZE
        material = physx.PhysxMaterial(TABLE_FRICTION, TABLE_FRICTION, 0.0)
        builder = self.scene.create_actor_builder()
        builder.add_box_collision(half_size=[hx, hy, hz], material=material)
        builder.add_box_visual(
            half_size=[hx, hy, hz], material=sapien.render.RenderMaterial(base_color=[0.6, 0.5, 0.4, 1])
        )
        builder.initial_pose = sapien.Pose(p=[0.0, 0.0, -hz])
        self.table = builder.build_static(name="table")
        floor = self.scene.create_actor_builder()
        floor.add_plane_collision(
            sapien.Pose(p=[0, 0, -2 * hz], q=[0.7071068, 0, -0.7071068, 0]), material=material
        )
        floor.initial_pose = sapien.Pose()
        self.floor = floor.build_static(name="floor")

    def _build_static_box(
        self,
        name: str,
        center: np.ndarray,
        half_size: np.ndarray,
        yaw: float | np.ndarray,
        color: tuple[float, float, float, float],
    ) -> Actor:
        """Build a static box at ``center`` (world) rotated by ``yaw`` about Z, or by ``yaw`` given as a
        (3, 3) rotation matrix (a tilted support)."""
        builder = self.scene.create_actor_builder()
        material = physx.PhysxMaterial(TABLE_FRICTION, TABLE_FRICTION, 0.0)
        builder.add_box_collision(half_size=list(half_size), material=material)
        builder.add_box_visual(
            half_size=list(half_size), material=sapien.render.RenderMaterial(base_color=list(color))
        )
        rotation = np.asarray(yaw, dtype=np.float64) if np.ndim(yaw) == 2 else yaw_matrix(float(yaw))
        builder.initial_pose = pose_from_matrix(np.asarray(center, dtype=np.float64), rotation)
        return builder.build_static(name=name)

    def _reset_hand(self) -> None:
        """Put the hand at its rest keyframe ("rest" if the agent defines one, else its first keyframe)."""
        if self.agent is None:
            return
        keyframes = self.agent.keyframes
        if not keyframes:
            return
        keyframe = keyframes.get("rest", next(iter(keyframes.values())))
        self.agent.robot.set_pose(keyframe.pose)
        self.agent.reset(torch.as_tensor(np.asarray(keyframe.qpos), dtype=torch.float32, device=self.device))

    # ------------------------------------------------------------------ executor API
    def _local_box_to_world(self, box: Box) -> WorldBox:
        position, rotation = pose_to_numpy(self.tool.pose.raw_pose)
        center, half = box
        return (
            position + rotation @ np.asarray(center, dtype=np.float64),
            np.asarray(half, dtype=np.float64).copy(),
            rotation,
        )

    def tool_gv_world(self) -> WorldBox:
        """T_gv in the world frame from the tool's simulated pose: (center (3,), half_extents (3,), R (3, 3))."""
        return self._local_box_to_world(self.tool_gv_local)

    def tool_fv_world(self) -> WorldBox:
        """T_fv in the world frame from the tool's simulated pose: (center (3,), half_extents (3,), R (3, 3))."""
        return self._local_box_to_world(self.tool_fv_local)

    def object_frame_world(self) -> tuple[np.ndarray, np.ndarray]:
        """The target object's frame in the world, (position (3,), R (3, 3)) with Z up."""
        raise NotImplementedError

    def step_physics(self) -> None:
        """One physics frame as ``env.step`` takes it: ``scene.step()``, then the task's per-frame watch
        (ManiSkill's ``_after_simulation_step``). The plan executor steps its frames with this, so a task that
        watches every frame (the hammer: what drives the nail) sees the same frames under both controllers."""
        self.scene.step()
        self._after_simulation_step()

    def bodies_pressing(self, body: Any, shape: Any = None) -> list[Any]:
        """The PhysX bodies pressing on the PhysX ``body`` now (on its collision ``shape`` only, if given):
        simulated contacts with a non-zero impulse (``presses``, asked only of the body's own contacts: the
        watches call this every frame), one entry per contact."""
        return [contact.bodies[1 - k] for contact in self.scene.px.get_contacts() for k in (0, 1)
                if contact.bodies[k] is body and (shape is None or contact.shapes[k] is shape) and presses(contact)]

    def hand_links_among(self, bodies: list[Any]) -> list[str]:
        """Names of the hand links among the PhysX ``bodies``. Empty without an agent."""
        hand = self._hand_link_names
        return sorted({hand[b.entity] for b in bodies if b.entity in hand})

    def hand_links_touching(self, body: Any, shape: Any = None) -> list[str]:
        """Names of the hand links pressing on the PhysX ``body`` now (``bodies_pressing``). Empty without an agent."""
        return self.hand_links_among(self.bodies_pressing(body, shape)) if self.agent is not None else []

    def tool_is_broken(self) -> torch.Tensor:
        """(1,) bool: the tool's simulated pose is NaN/inf (a PhysX blow-up) or it fell below the table top."""
        raw = self.tool.pose.raw_pose
        not_finite = ~torch.isfinite(raw).all(dim=-1)
        fell = raw[..., 2] < -0.05
        return not_finite | fell

    # ------------------------------------------------------------------ ManiSkill hooks
    def _get_obs_agent(self) -> dict:
        return {} if self.agent is None else super()._get_obs_agent()

    def get_state_dict(self) -> dict:
        """ManiSkill's state dict of this scene, complete: ``actors`` and ``articulations`` always present (the
        scene may have no free actor: the bottle), plus ``task``, what the task's per-frame watch has kept so far
        (``watch_state``), so a restored state evaluates and observes as the saved one did. Also works without
        an agent (``robot_uids="none"``, used by scene tests)."""
        state = self.scene.get_sim_state() if self.agent is None else super().get_state_dict()
        state = {"actors": state.pop("actors", {}), "articulations": state.pop("articulations", {}), **state}
        watch = self.watch_state()
        if watch:
            state["task"] = {name: torch.tensor([[float(value)]]) for name, value in watch.items()}
        return state

    def set_state_dict(self, state: dict, env_idx: torch.Tensor | None = None) -> None:
        """Restore a ``get_state_dict`` of this scene: bodies, joints and the watch's state."""
        super().set_state_dict({k: v for k, v in state.items() if k in ("actors", "articulations")}, env_idx)
        if "task" in state:
            self.set_watch_state({name: float(torch.as_tensor(v).reshape(-1)[0]) for name, v in state["task"].items()})

    def set_state(self, state: Any, env_idx: torch.Tensor | None = None) -> None:
        """Restore a flat ``get_state()`` vector. ManiSkill reads the vector with the layout of the first scene
        built; these scenes are rebuilt on every reset with their own bodies (a sweep's 6-8 cubes), so the layout
        is this scene's: the vector must come from a scene of the same seed. A vector of another length is an
        error naming both lengths."""
        state = torch.as_tensor(state)
        state = state[None] if state.ndim == 1 else state
        layout = self.get_state_dict()
        size = state_size(layout)
        if state.shape[-1] != size:
            raise ValueError(f"a flat state of {state.shape[-1]} values does not fit this scene's {size} "
                             f"(a state of another scene: reset with the seed it was taken on first)")
        self.set_state_dict(unflatten_state(state, layout)[0], env_idx)

    def on_stage_start(self, stage: str) -> None:
        """The plan executor calls this before the first physics frame of each stage it runs (``prl.stages``
        names), for every task alike; a task whose measure counts from a stage keeps its reference here (the
        unscrew counts the cap's turn from the motion on). Nothing by default. Controllers without stages (joint
        control, ``env.step``) never call it: such a measure then counts from the reset."""

    def failure_decided(self, stage: str, reach: HandReach) -> str:
        """Why this episode can no longer end in success, or "" when it still can (the default: never decided).

        Asked by the plan executor only with ``ExecutorConfig.end_decided``, at the boundary after each stage but
        the last (``stage`` has just ended, the next one has been planned), with ``reach`` the hand's remaining
        path. A non-empty answer ends the episode there as a failure. It must therefore hold for every way the
        rest of the episode can go: a task overrides this with the states its ``evaluate()`` can never turn into
        a success, and says why in its docstring. It must not change the simulation."""
        return ""

    def at_rest_out_of_reach(self, reach: HandReach) -> str:
        """Why nothing but the hand can move any more, or "": every body of the scene that can move, the hand
        aside (``envs.reach.moving_bodies``: the tool, debris, the mechanisms' moving links), is asleep in PhysX
        and the hand's remaining path stays more than ``REACH_MARGIN`` from each of them (``HandReach``).

        PhysX does not integrate a sleeping body: it stays where it is until an awake body touches it, an awake
        body of its island or a joint moves it, or the program moves or pushes it. Here no program does (the
        executor only writes the hand's drive targets; the mechanisms' drives are set once at the reset); the
        only other awake body is the hand (the sleeping bodies include every other one), and it stays clear of
        them. So from now on none of these bodies moves, and the hand touches none of them."""
        bodies = moving_bodies(self)
        if not all(b.is_sleeping if hasattr(b, "is_sleeping") else b.sleeping for b in bodies):
            return ""
        clearance = reach.clearance(bodies)
        if not clearance > REACH_MARGIN:
            return ""
        return f"every body but the hand asleep, {clearance * 100:.0f} cm or more from the hand's remaining path"

    def watch_state(self) -> dict[str, float]:
        """What the task's per-frame watch (``_after_simulation_step``) has kept in this episode, as named numbers
        (none by default); ``set_watch_state`` restores it."""
        return {}

    def set_watch_state(self, values: dict[str, float]) -> None:
        """Restore ``watch_state``; an unknown name is an error naming it."""
        if values:
            raise ValueError(f"{type(self).__name__} keeps no watch state; got {sorted(values)}")


def presses(contact: Any) -> bool:
    """Whether a PhysX contact presses: a non-zero impulse at some contact point (a touch, not a near miss)."""
    return any(np.abs(p.impulse).sum() > 0 for p in contact.points)


def state_size(layout: dict) -> int:
    """Number of values a ManiSkill state dict flattens to (``mani_skill.utils.common.flatten_state_dict``)."""
    return sum(state_size(v) if isinstance(v, dict) else int(torch.as_tensor(v).reshape(1, -1).shape[-1])
               for v in layout.values())


def unflatten_state(flat: torch.Tensor, layout: dict, start: int = 0) -> tuple[dict, int]:
    """The state dict of ``layout``'s shape read from ``flat`` (N, D) from column ``start``, in the order
    ``flatten_state_dict`` writes it; returns (dict, next column)."""
    out: dict = {}
    for name, value in layout.items():
        if isinstance(value, dict):
            out[name], start = unflatten_state(flat, value, start)
        else:
            width = int(torch.as_tensor(value).reshape(1, -1).shape[-1])
            out[name], start = flat[:, start:start + width], start + width
    return out, start

