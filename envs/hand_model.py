"""Generator of the PRL hand-arm URDF from the public Shadow Hand kinematics.

Input: ``assets/hand/shadow_kinematics.yaml`` (link tree, joint origins, axes and
limits, simple collision shapes, masses, anchor points). Output:
``assets/hand/prl_hand.urdf`` and ``assets/hand/prl_hand.srdf`` (collision pairs to
ignore, read by SAPIEN's URDF loader next to the URDF). ``python -m envs.hand_model``
regenerates both; the output is a pure function of the YAML (fixed number formats,
no timestamps), so regenerating gives identical bytes.

Palm frame convention (Shadow Hand): origin on the WRJ1 axis, +Z along the
fingers, -Y the palm normal, +X towards the thumb. The six palm anchor points
(paper Fig 3) are given in that frame by :func:`palm_anchors`.
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from prl.constants import JOINT_NAMES, N_ANCHORS, SENSOR_NAMES

HAND_DIR = Path(__file__).resolve().parents[1] / "assets" / "hand"
KINEMATICS_PATH = HAND_DIR / "shadow_kinematics.yaml"
URDF_PATH = HAND_DIR / "prl_hand.urdf"
SRDF_PATH = HAND_DIR / "prl_hand.srdf"

#: Lower bound on principal inertias (kg m^2) of links without shapes.
_MIN_INERTIA = 1e-6


class HandModelError(ValueError):
    """The kinematics YAML is malformed; the message names the bad value."""


@dataclass(frozen=True)
class HandSpec:
    """The parsed kinematics YAML."""

    raw: dict[str, Any]
    """The YAML document as loaded."""

    @property
    def links(self) -> list[dict[str, Any]]:
        """Link entries in tree order."""
        return self.raw["links"]

    @property
    def anchors(self) -> np.ndarray:
        """(6, 3) anchor points in the palm frame, metres."""
        return np.asarray(self.raw["anchors"], dtype=np.float64)

    @property
    def palm_centre(self) -> np.ndarray:
        """(3,) palm centre (the arm's rotation centre) in the palm frame."""
        return np.asarray(self.raw["palm_centre"], dtype=np.float64)

    def joint_limits(self) -> dict[str, tuple[float, float]]:
        """Published (lower, upper) limit of every movable joint by name."""
        out = {}
        for link in self.links:
            joint = link.get("joint")
            if joint and joint["type"] != "fixed":
                out[joint["name"]] = (float(joint["limit"][0]), float(joint["limit"][1]))
        return out


def load_spec(path: Path | str = KINEMATICS_PATH) -> HandSpec:
    """Load and validate the kinematics YAML."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"hand kinematics file not found: {path}")
    raw = yaml.safe_load(path.read_text())
    spec = HandSpec(raw)
    names = [link["name"] for link in spec.links]
    if len(set(names)) != len(names):
        raise HandModelError(f"duplicate link names in {path}: {names}")
    joints = [link["joint"]["name"] for link in spec.links if link.get("joint") and link["joint"]["type"] != "fixed"]
    if tuple(joints) != JOINT_NAMES:
        raise HandModelError(f"movable joints {joints} are not JOINT_NAMES {list(JOINT_NAMES)}")
    missing = [s for s in SENSOR_NAMES if s not in names]
    if missing:
        raise HandModelError(f"sensor links {missing} are not links of the hand")
    if spec.anchors.shape != (N_ANCHORS, 3):
        raise HandModelError(f"anchors must be {N_ANCHORS} x 3, got shape {spec.anchors.shape}")
    seen = set()
    for link in spec.links:
        parent = link.get("parent")
        if parent is not None and parent not in seen:
            raise HandModelError(f"link {link['name']!r}: parent {parent!r} not defined before it")
        seen.add(link["name"])
        for shape in link.get("shapes", []):
            if shape["kind"] not in ("box", "capsule", "sphere"):
                raise HandModelError(f"link {link['name']!r}: unknown shape kind {shape['kind']!r}")
    return spec


@functools.lru_cache(maxsize=1)
def default_spec() -> HandSpec:
    """The spec of ``assets/hand/shadow_kinematics.yaml`` (loaded once per process)."""
    return load_spec(KINEMATICS_PATH)


def palm_anchors() -> np.ndarray:
    """(6, 3) palm anchor points in the palm-link frame (fingers +Z, palm normal -Y), metres."""
    return default_spec().anchors.copy()


def palm_centre() -> np.ndarray:
    """(3,) the palm centre in the palm-link frame (the arm's rotation centre at wrist = 0)."""
    return default_spec().palm_centre.copy()


# --------------------------------------------------------------------------- inertia
def _shape_volume(shape: dict[str, Any]) -> float:
    kind = shape["kind"]
    if kind == "box":
        sx, sy, sz = shape["size"]
        return sx * sy * sz
    if kind == "sphere":
        return 4.0 / 3.0 * math.pi * shape["radius"] ** 3
    r, h = shape["radius"], shape["length"]
    return math.pi * r * r * h + 4.0 / 3.0 * math.pi * r**3


def _shape_inertia(shape: dict[str, Any], mass: float) -> np.ndarray:
    """Inertia (3, 3) of a solid shape of ``mass`` about its own centre, shape axes."""
    kind = shape["kind"]
    if kind == "box":
        sx, sy, sz = shape["size"]
        return np.diag([sy * sy + sz * sz, sx * sx + sz * sz, sx * sx + sy * sy]) * mass / 12.0
    if kind == "sphere":
        return np.eye(3) * 0.4 * mass * shape["radius"] ** 2
    # capsule approximated as a solid cylinder of the full length (cylinder + 2 radii)
    r, h = shape["radius"], shape["length"] + 2 * shape["radius"]
    ixx = mass * (3 * r * r + h * h) / 12.0
    return np.diag([ixx, ixx, 0.5 * mass * r * r])


def link_inertial(link: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Centre of mass (3,) and diagonal inertia (3,) about it (link axes) for a link entry."""
    mass = float(link.get("mass", 0.0))
    shapes = [s for s in link.get("shapes", []) if not s.get("visual_only")]
    if not shapes:
        inertia = max(_MIN_INERTIA, 0.4 * mass * 0.01**2)
        return np.zeros(3), np.full(3, inertia)
    volumes = np.array([_shape_volume(s) for s in shapes])
    masses = mass * volumes / volumes.sum()
    centres = np.array([s.get("origin", [0.0, 0.0, 0.0]) for s in shapes], dtype=np.float64)
    com = (masses[:, None] * centres).sum(0) / mass
    total = np.zeros((3, 3))
    for shape, m, c in zip(shapes, masses, centres, strict=True):
        d = c - com
        total += _shape_inertia(shape, m) + m * (np.dot(d, d) * np.eye(3) - np.outer(d, d))
    return com, np.maximum(np.diag(total), _MIN_INERTIA)


# --------------------------------------------------------------------------- writers
def _f(x: float) -> str:
    """Fixed, round-trippable number format (deterministic output)."""
    value = float(x)
    if value == 0.0:
        return "0"
    return repr(round(value, 9))


def _vec(values: Any) -> str:
    return " ".join(_f(v) for v in values)


def _geometry(shape: dict[str, Any]) -> str:
    kind = shape["kind"]
    if kind == "box":
        return f'<box size="{_vec(shape["size"])}"/>'
    if kind == "sphere":
        return f'<sphere radius="{_f(shape["radius"])}"/>'
    return f'<capsule radius="{_f(shape["radius"])}" length="{_f(shape["length"])}"/>'


def build_urdf(spec: HandSpec) -> str:
    """The URDF text for ``spec``."""
    colors = spec.raw.get("colors", {})
    lines = ['<?xml version="1.0"?>',
             "<!-- Generated by envs/hand_model.py from assets/hand/shadow_kinematics.yaml. Do not edit. -->",
             f'<robot name="{spec.raw["name"]}">']
    for name in sorted(colors):
        lines.append(f'  <material name="{name}"><color rgba="{_vec(colors[name])}"/></material>')
    for link in spec.links:
        lines.append(f'  <link name="{link["name"]}">')
        mass = float(link.get("mass", 0.0))
        if mass > 0:
            com, inertia = link_inertial(link)
            lines.append("    <inertial>")
            lines.append(f'      <origin xyz="{_vec(com)}" rpy="0 0 0"/>')
            lines.append(f'      <mass value="{_f(mass)}"/>')
            lines.append(f'      <inertia ixx="{_f(inertia[0])}" ixy="0" ixz="0" iyy="{_f(inertia[1])}" '
                         f'iyz="0" izz="{_f(inertia[2])}"/>')
            lines.append("    </inertial>")
        for i, shape in enumerate(link.get("shapes", [])):
            origin = f'<origin xyz="{_vec(shape.get("origin", [0, 0, 0]))}" rpy="{_vec(shape.get("rpy", [0, 0, 0]))}"/>'
            color = link.get("color")
            material = f'<material name="{color}"/>' if color else ""
            lines.append(f'    <visual name="{link["name"]}_visual_{i}">{origin}<geometry>{_geometry(shape)}</geometry>'
                         f"{material}</visual>")
            if not shape.get("visual_only"):
                lines.append(f'    <collision name="{link["name"]}_collision_{i}">{origin}'
                             f"<geometry>{_geometry(shape)}</geometry></collision>")
        lines.append("  </link>")
    for link in spec.links:
        joint = link.get("joint")
        if not joint:
            continue
        lines.append(f'  <joint name="{joint["name"]}" type="{joint["type"]}">')
        lines.append(f'    <parent link="{link["parent"]}"/>')
        lines.append(f'    <child link="{link["name"]}"/>')
        lines.append(f'    <origin xyz="{_vec(joint.get("origin", [0, 0, 0]))}" rpy="{_vec(joint.get("rpy", [0, 0, 0]))}"/>')
        if joint["type"] != "fixed":
            lines.append(f'    <axis xyz="{_vec(joint["axis"])}"/>')
            lo, hi = joint["limit"]
            lines.append(f'    <limit lower="{_f(lo)}" upper="{_f(hi)}" effort="1000" velocity="100"/>')
        lines.append("  </joint>")
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def build_srdf(spec: HandSpec) -> str:
    """The SRDF text: link pairs whose collisions SAPIEN should ignore (reason "Default")."""
    lines = ['<?xml version="1.0"?>',
             "<!-- Generated by envs/hand_model.py from assets/hand/shadow_kinematics.yaml. Do not edit. -->",
             f'<robot name="{spec.raw["name"]}">']
    for a, b in spec.raw.get("disable_collisions", []):
        lines.append(f'  <disable_collisions link1="{a}" link2="{b}" reason="Default"/>')
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def generate(kinematics: Path | str = KINEMATICS_PATH, urdf_out: Path | str = URDF_PATH) -> tuple[Path, Path]:
    """Write the URDF (and the SRDF next to it, same stem) from the kinematics YAML; return both paths."""
    spec = load_spec(kinematics)
    urdf_out = Path(urdf_out)
    srdf_out = urdf_out.with_suffix(".srdf")
    urdf_out.parent.mkdir(parents=True, exist_ok=True)
    urdf_out.write_text(build_urdf(spec))
    srdf_out.write_text(build_srdf(spec))
    return urdf_out, srdf_out


def verify_generated(kinematics: Path | str = KINEMATICS_PATH, urdf: Path | str = URDF_PATH) -> str:
    """Check the committed URDF/SRDF equal what the generator writes now; return the URDF's sha256.

    Raises ``HandModelError`` naming the stale or missing file (regenerate with
    ``python -m envs.hand_model``).
    """
    spec = load_spec(kinematics)
    urdf = Path(urdf)
    for path, text in ((urdf, build_urdf(spec)), (urdf.with_suffix(".srdf"), build_srdf(spec))):
        if not path.is_file():
            raise HandModelError(f"hand model file {str(path)!r} is missing; run `python -m envs.hand_model`")
        if path.read_text() != text:
            raise HandModelError(f"hand model file {str(path)!r} is stale; run `python -m envs.hand_model`")
    return hashlib.sha256(urdf.read_bytes()).hexdigest()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kinematics", default=str(KINEMATICS_PATH), help="input YAML")
    parser.add_argument("--out", default=str(URDF_PATH), help="output URDF (the SRDF goes next to it)")
    args = parser.parse_args(argv)
    urdf, srdf = generate(args.kinematics, args.out)
    print(f"wrote {urdf} and {srdf}")


if __name__ == "__main__":
    main()
