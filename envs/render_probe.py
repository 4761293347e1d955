"""Start-up probe: SAPIEN version, Mesa/Vulkan device, and whether rendering works.

``python -m envs.render_probe`` prints a report. Code that needs images calls
:func:`require_rendering`, which raises :class:`RenderingUnavailable` with the
reason and the fix instead of failing silently or returning black frames.

The render test runs in a subprocess, so a crashing Vulkan driver cannot take
the caller down; its result is remembered for the life of the process.
"""

from __future__ import annotations

import functools
import json
import os
import subprocess
import sys
from dataclasses import asdict, dataclass

_RENDER_SNIPPET = r"""
import json, sapien
out = {"sapien": sapien.__version__, "device": "", "ok": False, "error": ""}
try:
    out["device"] = sapien.render.get_device_summary().splitlines()[0].strip()
    scene = sapien.Scene()
    b = scene.create_actor_builder()
    b.add_box_visual(half_size=[0.1, 0.1, 0.1], material=[1, 0, 0])
    b.build_static().set_pose(sapien.Pose([0, 0, 0]))
    scene.set_ambient_light([0.6, 0.6, 0.6])
    cam = scene.add_camera("probe", 32, 32, 1.0, 0.01, 10.0)
    cam.set_local_pose(sapien.Pose([-1.0, 0, 0]))
    scene.update_render()
    cam.take_picture()
    img = cam.get_picture("Color")
    out["ok"] = bool(img[..., :3].max() > 0.05)
    if not out["ok"]:
        out["error"] = "rendered image is black"
except Exception as e:  # noqa: BLE001 - report any driver failure
    out["error"] = f"{type(e).__name__}: {e}"
print("PROBE" + json.dumps(out))
"""

FIX_HINT = (
    "Headless rendering needs a Vulkan device; on a machine without a GPU install Mesa's lavapipe "
    ">= 24.3 (Debian 12: `apt-get install -t bookworm-backports mesa-vulkan-drivers`, done by "
    "`bash scripts/setup.sh`) and set XDG_RUNTIME_DIR to a writable directory."
)


class RenderingUnavailable(RuntimeError):
    """Raised when a caller asks for images and no working Vulkan renderer exists."""


@dataclass(frozen=True)
class ProbeReport:
    """What the probe found."""

    sapien: str
    mesa_vulkan_drivers: str
    device: str
    rendering: bool
    error: str


def mesa_version() -> str:
    """Installed version of Debian's ``mesa-vulkan-drivers`` ('' when unknown)."""
    try:
        res = subprocess.run(
            ["dpkg-query", "-W", "-f=${Version}", "mesa-vulkan-drivers"],
            capture_output=True, text=True, timeout=10, check=False,
        )
        return res.stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        return ""


@functools.cache
def probe() -> ProbeReport:
    """Run the render test in a subprocess and report (cached per process)."""
    env = dict(os.environ)
    env.setdefault("XDG_RUNTIME_DIR", "/tmp/prl-runtime")
    os.makedirs(env["XDG_RUNTIME_DIR"], exist_ok=True)
    try:
        res = subprocess.run(
            [sys.executable, "-c", _RENDER_SNIPPET], capture_output=True, text=True, timeout=120, env=env,
            check=False,
        )
        line = next((ln for ln in res.stdout.splitlines() if ln.startswith("PROBE")), None)
        if line is None:
            tail = (res.stderr or res.stdout).strip().splitlines()[-1:] or [f"exit code {res.returncode}"]
            data = {"sapien": "", "device": "", "ok": False, "error": f"probe crashed: {tail[0]}"}
        else:
            data = json.loads(line[len("PROBE"):])
    except subprocess.TimeoutExpired:
        data = {"sapien": "", "device": "", "ok": False, "error": "probe timed out after 120 s"}
    return ProbeReport(
        sapien=data["sapien"], mesa_vulkan_drivers=mesa_version(), device=data["device"],
        rendering=data["ok"], error=data["error"],
    )


def require_rendering(purpose: str = "images") -> ProbeReport:
    """Return the probe report, or raise :class:`RenderingUnavailable` naming why and the fix."""
    report = probe()
    if not report.rendering:
        raise RenderingUnavailable(
            f"cannot render {purpose}: {report.error or 'no Vulkan device'} "
            f"(mesa-vulkan-drivers {report.mesa_vulkan_drivers or 'not installed'}). {FIX_HINT}"
        )
    return report


def main() -> None:
    report = probe()
    for key, value in asdict(report).items():
        print(f"{key:>20}: {value}")
    if not report.rendering:
        print(FIX_HINT)
        sys.exit(1)


if __name__ == "__main__":
    main()
