"""Pictures of a plan episode: one PNG of the scene at the end of each executor stage.

``python -m envs.render_stages --task hammer --plan 0,3,2,0,0,1 --seed 0 --out outputs/stages``
resets the task with ``seed``, renders the initial scene, executes ``plan`` with
:class:`envs.executor.PlanExecutor` and renders the scene after the last physics frame of every
stage (``PlanExecutor.run(..., on_stage_end=...)``). It writes ``00_initial.png``,
``01_pregrasp.png`` ... ``07_motion.png`` and a contact sheet ``stages.png`` (all pictures in a
grid, titled with the stage names), then prints the paths and the episode outcome.

The pictures come from a SAPIEN camera added to the rebuilt scene after the reset (the PRL tasks
rebuild their scene on every reset, so a camera can only be added afterwards); the lights are
the task's (ManiSkill's default ``_load_lighting``). Rendering only reads the simulated poses
(``scene.update_render()``), so the episode's physics and outcome are those of a plain run.
Rendering needs a working Vulkan device (``python -m envs.render_probe``);
:func:`render_stages` raises :class:`envs.render_probe.RenderingUnavailable` otherwise.
"""

from __future__ import annotations

import argparse
import os
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import sapien

from envs.executor import PlanExecutor
from envs.render_probe import require_rendering
from envs.tasks import TASK_ENV_IDS, make_env, task_class
from envs.tasks.grasp_probe import PROBE_OBJECTS, make_probe_env
from prl import labels
from prl.constants import SENSOR_NAMES
from prl.label_recovery import CONTACT_THRESHOLD_N
from prl.plb import PLBError, parse_plan
from prl.stages import STAGES

IMAGE_SIZE = (512, 384)
"""(width, height) of each stage picture, pixels."""


@dataclass(frozen=True)
class View:
    """A pinhole camera looking from ``eye`` at ``target`` (metres), Z up.

    ``follow_tool=False``: ``eye`` and ``target`` are world points (a fixed camera);
    ``True``: they are offsets from the tool's grasp-volume centre, re-aimed at every picture.
    """

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    fovy_deg: float = 45.0
    follow_tool: bool = False


VIEWS: dict[str, View] = {
    # fixed, from the front-right of the table (~60 deg from +X, ~25 deg down): rack + hammer on
    # the left, board + nail on the right, the hand above them, fingers wrapping towards the camera
    "workspace": View(eye=(0.33, -0.51, 0.39), target=(0.035, 0.005, 0.14), fovy_deg=42.0),
    # close-up that follows the hammer's handle (hand and grasp fill the picture)
    "closeup": View(eye=(0.12, -0.22, 0.12), target=(0.02, 0.0, -0.01), fovy_deg=45.0, follow_tool=True),
    # close-up from below and in front of the tool, which it follows: what the fingers (or tweezers' tips) hold
    # under the hand, e.g. the cube between the tips once lifted
    "below": View(eye=(-0.05, -0.26, -0.06), target=(-0.06, 0.0, 0.0), fovy_deg=45.0, follow_tool=True),
}
"""Named camera views; ``workspace`` is the default."""


@dataclass
class StagePictures:
    """What :func:`render_stage_pictures` produced."""

    paths: list[Path]
    """Stage pictures in order: ``00_initial.png``, then one per executor stage."""
    sheet: Path
    """The contact sheet ``stages.png``."""
    result: Any
    """The :class:`envs.execution.EpisodeResult` of the episode."""
    stage_frames: dict[str, int] = field(default_factory=dict)
    """Physics frame index each picture was taken after (-1 for the initial scene)."""


def look_at(eye: np.ndarray, target: np.ndarray, up: tuple[float, float, float] = (0.0, 0.0, 1.0)) -> Any:
    """A ``sapien.Pose`` for a SAPIEN camera (x forward, y left, z up) at ``eye`` looking at ``target``, with
    ``up`` (in the same frame; Z by default) pointing up in the picture."""
    up = np.asarray(up, dtype=np.float64)
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    forward /= np.linalg.norm(forward)
    left = np.cross(up, forward)
    left /= np.linalg.norm(left)
    cam_up = np.cross(forward, left)
    m = np.eye(4)
    m[:3, :3] = np.column_stack([forward, left, cam_up])
    m[:3, 3] = eye
    return sapien.Pose(m)


def add_camera(env: Any, view: View, size: tuple[int, int] = IMAGE_SIZE, name: str = "stage_camera") -> Any:
    """Add a camera to the (already reset) scene of ``env``; returns the SAPIEN camera component."""
    scene = env.unwrapped.scene.sub_scenes[0]
    width, height = size
    camera = scene.add_camera(name, int(width), int(height), float(np.deg2rad(view.fovy_deg)), 0.01, 10.0)
    aim_camera(env, camera, view)
    return camera


def aim_camera(env: Any, camera: Any, view: View) -> None:
    """Point ``camera`` as ``view`` says (for ``follow_tool`` views: at the tool's current position)."""
    eye, target = np.array(view.eye, dtype=np.float64), np.array(view.target, dtype=np.float64)
    if view.follow_tool:
        center = env.unwrapped.tool_gv_world()[0]
        if np.all(np.isfinite(center)):
            eye, target = eye + center, target + center
    camera.set_local_pose(look_at(eye, target))


def take_picture(env: Any, camera: Any, view: View | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB picture of the current simulated state (re-aimed first if ``view`` follows the tool)."""
    if view is not None and view.follow_tool:
        aim_camera(env, camera, view)
    env.unwrapped.scene.sub_scenes[0].update_render()
    camera.take_picture()
    rgba = np.asarray(camera.get_picture("Color"), dtype=np.float32)
    return (np.clip(rgba[..., :3], 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _save_png(image: np.ndarray, path: Path) -> None:
    from PIL import Image  # optional: only rendering needs Pillow

    Image.fromarray(image).save(path)


def contact_sheet(images: list[np.ndarray], titles: list[str], path: Path, columns: int = 4,
                  suptitle: str = "") -> Path:
    """Save a grid of ``images`` titled ``titles`` to ``path`` (PNG) and return ``path``."""
    import matplotlib  # heavy: only pictures need matplotlib

    matplotlib.use("Agg")  # headless; set before pyplot is imported
    import matplotlib.pyplot as plt  # heavy: as above

    rows = (len(images) + columns - 1) // columns
    h, w = images[0].shape[:2]
    title_lines = max(t.count("\n") + 1 for t in titles)  # room above each row for multi-line titles
    fig, axes = plt.subplots(rows, columns, figsize=(columns * 3.2 * w / h * 0.75 + 0.2,
                                                     rows * (2.6 + 0.17 * title_lines) + 0.6), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for ax, image, title in zip(axes.flat, images, titles):
        ax.imshow(image)
        ax.set_title(title, fontsize=10 if title_lines == 1 else 8)
    if suptitle:
        fig.suptitle(suptitle, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def render_stage_pictures(task: str, plan: Any, seed: int, out_dir: str | os.PathLike,
                          view: str | View = "workspace", size: tuple[int, int] = IMAGE_SIZE) -> StagePictures:
    """Execute ``plan`` on ``task`` with scene ``seed`` and save a picture of each stage end to ``out_dir``."""
    require_rendering("stage pictures")

    view = VIEWS[view] if isinstance(view, str) else view
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    env = make_env(task)
    try:
        executor = PlanExecutor(env)
        plan = executor.validate(plan)
        env.reset(seed=int(seed))  # the scene is rebuilt on reset: add the camera afterwards
        camera = add_camera(env, view, size)
        images: list[np.ndarray] = [take_picture(env, camera, view)]
        titles = ["initial"]
        frames = {"initial": -1}

        def on_stage_end(stage: str, frame: int) -> None:
            images.append(take_picture(env, camera, view))
            titles.append(stage)
            frames[stage] = frame

        result = executor.run(plan, seed=None, on_stage_end=on_stage_end)  # None: keep the reset scene
        description = executor.plb.describe(plan)
    finally:
        env.close()

    paths = []
    for i, (image, title) in enumerate(zip(images, titles)):
        path = out / f"{i:02d}_{title}.png"
        _save_png(image, path)
        paths.append(path)
    key = type(env.unwrapped).measure_key
    measure = result.outcome.get(key)
    labels = [f"{i:02d} {t}" + ("" if frames[t] < 0 else f" (frame {frames[t]})") for i, t in enumerate(titles)]
    suptitle = (f"{task}, seed {seed}, {description}\nsuccess={result.success}"
                + (f", {key.replace('_', ' ')} {measure:.2f}" if isinstance(measure, (int, float)) else ""))
    sheet = contact_sheet(images, labels, out / "stages.png", suptitle=suptitle)
    missing = [s for s, _ in type(env.unwrapped).stages.shares if s not in frames]
    if missing:
        result.notes.append(f"no pictures of stages never reached: {missing}")
    return StagePictures(paths=paths, sheet=sheet, result=result, stage_frames=frames)


def render_stages(task: str, plan: Any, seed: int, out_dir: str | os.PathLike) -> list[Path]:
    """Render each stage of ``plan`` on ``task`` (scene ``seed``) to ``out_dir``.

    Returns the written files: ``00_initial.png``, one ``NN_<stage>.png`` per executor stage,
    then the contact sheet ``stages.png`` (last). Raises ``RenderingUnavailable`` when no
    Vulkan renderer works, ``ValueError`` for an unknown task or an invalid plan.
    """
    pictures = render_stage_pictures(task, plan, seed, out_dir)
    return [*pictures.paths, pictures.sheet]


GRASP_VIEW = View(eye=(-0.16, -0.12, 0.04), target=(0.0, 0.0, 0.0), fovy_deg=45.0, follow_tool=True)
"""Close-up of a grasp from the front-left of the reference object, following it."""


def render_grasp_patterns(out_dir: str | os.PathLike, seed: int = 0) -> Path:
    """One picture per catalogue grasp pattern, its posture holding its reference object (the grasp probe
    of ``envs/tasks/grasp_probe.py``) at the end of the lift, titled with the sensors in contact and the
    pattern Eq 6 reads from them; saved as the contact sheet ``grasp_patterns.png`` in ``out_dir``."""
    require_rendering("grasp pattern pictures")

    images, titles = [], []
    for kind, spec in PROBE_OBJECTS.items():
        env = make_probe_env(kind)
        try:
            executor = PlanExecutor(env)
            env.reset(seed=int(seed))
            camera = add_camera(env, GRASP_VIEW)
            shots: dict[str, np.ndarray] = {}

            def on_stage_end(stage: str, frame: int) -> None:
                if stage == "lift":
                    shots[stage] = take_picture(env, camera, GRASP_VIEW)

            result = executor.run(spec["plan"], seed=None, on_stage_end=on_stage_end)
        finally:
            env.close()
        lift = result.stage == STAGES.index("lift")
        held = labels.binarize_contacts(result.force[lift], CONTACT_THRESHOLD_N).mean(axis=0) >= 0.5
        read = labels.grasp_label(held.astype(np.uint8), executor.plb.grasp_matrix())
        names = [SENSOR_NAMES[i] for i in np.flatnonzero(held)]
        images.append(shots["lift"])
        reads = executor.plb.dims[3].choices[read] if read >= 0 else "nothing"
        touching = textwrap.fill(", ".join(n.replace("_", " ") for n in names), width=48)
        titles.append(f"{spec['pattern']} on the {kind}, lifted {result.outcome['lift_cm']:.0f} cm\n"
                      f"Eq 6 reads {reads}\n{touching}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return contact_sheet(images, titles, out / "grasp_patterns.png", columns=2,
                         suptitle=f"grasp patterns on their reference objects (seed {seed}): end of the lift")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Render a picture of each plan-executor stage to PNG.")
    parser.add_argument("--task", default="hammer", choices=sorted(TASK_ENV_IDS))
    parser.add_argument("--plan", default=None, help="e.g. 0,3,2,0,0,1 (default: the task's expert plan)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="outputs/stages", help="output folder")
    parser.add_argument("--view", choices=sorted(VIEWS), default="workspace")
    parser.add_argument("--grasp-patterns", action="store_true",
                        help="instead: one picture per grasp pattern on its reference object (grasp_patterns.png)")
    args = parser.parse_args(argv)
    try:
        plan = parse_plan(args.plan) if args.plan is not None else task_class(args.task).expert_plan
    except PLBError as exc:
        parser.error(f"--plan: {exc}")
    os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp/prl-runtime")
    os.makedirs(os.environ["XDG_RUNTIME_DIR"], exist_ok=True)
    if args.grasp_patterns:
        print(render_grasp_patterns(args.out, args.seed))
        return

    pictures = render_stage_pictures(args.task, plan, args.seed, args.out, view=args.view)
    for path in [*pictures.paths, pictures.sheet]:
        print(path)
    result = pictures.result
    print(f"success={result.success} " + " ".join(f"{k}={v}" for k, v in result.outcome.items() if k != "success")
          + (f" notes={result.notes}" if result.notes else ""))


if __name__ == "__main__":
    main()
