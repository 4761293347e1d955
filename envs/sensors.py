"""The 17 contact-sensor patches of the hand (paper Sec III, Fig 3), read from PhysX contacts.

Each sensor is one hand link (``prl.constants.SENSOR_NAMES``). For every PhysX contact pair
between a sensor link and a body that is not part of the hand, the per-point impulses are
summed; the sensor reports

* ``force``: |sum of impulses| / dt (N): the net contact force on the link;
* ``position``: the contact points' mean weighted by their impulse magnitudes (world, m);
  unweighted mean when the pair touches with zero impulse;
* ``normal``: unit direction of the net contact force acting *on the hand link* (world),
  i.e. pointing from the touched body into the link; from the summed contact normals when
  the impulses are zero.

Sensors without contact read zeros. Cost: one ``get_contacts()`` call and a Python loop over
the (few) contact pairs of the scene.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from prl.constants import N_SENSORS

_ZERO3 = np.zeros(3)


def _components(link: Any) -> list[Any]:
    """The PhysX body components behind a ManiSkill ``Link``/``Actor`` or a raw component."""
    if hasattr(link, "_bodies"):
        return list(link._bodies)
    if hasattr(link, "_objs"):
        return list(link._objs)
    return [link]


class ContactSensors:
    """Reusable reader: resolves the link components once, then ``read()`` every frame."""

    def __init__(self, scene: Any, hand_links: Sequence[Any], exclude: Any = None) -> None:
        """``scene``: ManiSkill scene (or anything with ``.px`` = PhysX CPU system);
        ``hand_links``: the 17 sensor links in ``SENSOR_NAMES`` order; ``exclude``: an
        articulation (or links) whose bodies are ignored as contact partners (the hand itself)."""
        if len(hand_links) != N_SENSORS:
            raise ValueError(f"expected {N_SENSORS} sensor links, got {len(hand_links)}")
        self.px = scene.px if hasattr(scene, "px") else scene
        self.index: dict[Any, int] = {}
        for i, link in enumerate(hand_links):
            for component in _components(link):
                self.index[component] = i
        self.excluded: set[Any] = set(self.index)
        if exclude is not None:
            links = exclude.get_links() if hasattr(exclude, "get_links") else exclude
            for link in links if isinstance(links, Iterable) else [links]:
                self.excluded.update(_components(link))

    def read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(force (17,), position (17, 3), normal (17, 3)) of the last physics step."""
        index, excluded = self.index, self.excluded
        rows: list[int] = []
        signs: list[float] = []
        impulses: list[Any] = []
        positions: list[Any] = []
        normals: list[Any] = []
        for contact in self.px.get_contacts():
            b0, b1 = contact.bodies
            i0 = index.get(b0)
            if i0 is not None and b1 not in excluded:
                i, sign = i0, 1.0
            else:
                i1 = index.get(b1)
                if i1 is not None and b0 not in excluded:
                    i, sign = i1, -1.0
                else:
                    continue
            for point in contact.points:
                impulse = point.impulse
                rows.append(i)
                signs.append(sign)
                impulses.append(impulse)
                positions.append(point.position)
                # the normal is only needed where the impulse is zero (reading it costs ~us)
                normals.append(point.normal if not impulse.any() else _ZERO3)
        force = np.zeros(N_SENSORS)
        position = np.zeros((N_SENSORS, 3))
        normal = np.zeros((N_SENSORS, 3))
        if not rows:
            return force, position, normal
        # PhysX: a point's impulse and normal act on body 0 (pointing from body 1 into body 0).
        n_points = len(rows)
        sign = np.asarray(signs)[:, None]
        imp = np.asarray(impulses, dtype=np.float64) * sign
        pos = np.asarray(positions, dtype=np.float64)
        mag = np.sqrt(np.einsum("ij,ij->i", imp, imp))
        data = np.empty((n_points, 13))
        data[:, 0:3] = imp
        data[:, 3:6] = pos * mag[:, None]
        data[:, 6:9] = pos
        data[:, 9:12] = np.asarray(normals, dtype=np.float64) * sign
        data[:, 12] = mag
        onehot = np.zeros((N_SENSORS, n_points))
        onehot[rows, np.arange(n_points)] = 1.0
        sums = onehot @ data  # per-sensor sums
        count = onehot.sum(axis=1)
        impulse, weight = sums[:, 0:3], sums[:, 12]
        impulse_norm = np.sqrt(np.einsum("ij,ij->i", impulse, impulse))
        force = impulse_norm / self.px.timestep
        has_weight = weight > 0
        position[has_weight] = sums[has_weight, 3:6] / weight[has_weight, None]
        only_touch = (~has_weight) & (count > 0)
        position[only_touch] = sums[only_touch, 6:9] / count[only_touch, None]
        direction = np.where((impulse_norm > 0)[:, None], impulse, sums[:, 9:12])
        norm = np.sqrt(np.einsum("ij,ij->i", direction, direction))
        ok = norm > 1e-12
        normal[ok] = direction[ok] / norm[ok, None]
        return force, position, normal


def read_contacts(scene: Any, hand_links: Sequence[Any], exclude: Any = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-shot read: (force (17,), position (17, 3), normal (17, 3)) of the 17 sensor links'
    contacts with bodies outside ``exclude`` (the hand). For per-frame use build a
    :class:`ContactSensors` once and call ``read()``."""
    return ContactSensors(scene, hand_links, exclude).read()
