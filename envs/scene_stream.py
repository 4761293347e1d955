"""The scene-seed stream of the LN's environments (plan and joint control alike).

Episode ``i`` of the stream ``(run_seed, rank)`` runs on ``ln_scene_seed(run_seed, rank, i)``;
``reset(seed=s)`` restarts the stream at episode 0 with run seed ``s``, and
``reset(options={"scene_seed": n})`` runs one episode on scene ``n`` without advancing the stream
(evaluation).
"""

from __future__ import annotations

import zlib
from typing import Any


def ln_scene_seed(run_seed: int, rank: int, episode: int) -> int:
    """Scene seed of LN training episode ``episode`` of environment ``rank`` in a run seeded ``run_seed``.

    A hash, so it does not meet the RN evaluation's consecutive seeds (10,000,000 + ...) on which the
    final policy is evaluated, nor the trials' seeds, except by a 1-in-4-billion chance per pair."""
    return zlib.crc32(f"ln/{int(run_seed)}/{int(rank)}/{int(episode)}".encode())


class SceneStream:
    """The scene-seed stream of the LN's environments: ``run_seed``, ``rank``, the next ``episode`` and the
    current ``scene_seed`` (see the module docstring)."""

    run_seed: int
    rank: int
    episode: int = 0
    scene_seed: int | None = None

    def next_scene(self, seed: int | None, options: dict[str, Any] | None) -> int:
        """The scene of the episode a ``reset(seed=..., options=...)`` starts (and the stream advanced past it)."""
        if seed is not None:
            self.run_seed, self.episode = int(seed), 0
        if options and "scene_seed" in options:
            self.scene_seed = int(options["scene_seed"])
        else:
            self.scene_seed = ln_scene_seed(self.run_seed, self.rank, self.episode)
            self.episode += 1
        return self.scene_seed
