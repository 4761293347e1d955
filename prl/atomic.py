"""The project's one atomic file write: a temporary sibling ``.<name>.tmp``, flushed, synced, then renamed.

A reader sees the old file or the new one, never a torn one; a write cut by a kill leaves only the
temporary file, which a resuming writer may look for (synthesis removes ``.ep*.npz.tmp``).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO


def temporary_path(path: Path) -> Path:
    """Where ``atomic_file`` writes ``path`` before the rename: ``.<name>.tmp`` beside it."""
    path = Path(path)
    return path.with_name(f".{path.name}.tmp")


@contextmanager
def atomic_file(path: Path, mode: str = "wb") -> Iterator[IO]:
    """Open ``temporary_path(path)`` for writing; on a clean exit sync it and rename it onto ``path``.

    The parent directory is created. On an exception the temporary file is removed and ``path`` keeps
    what it held."""
    if "w" not in mode:
        raise ValueError(f"atomic_file writes a whole file: mode must contain 'w', got {mode!r}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_path(path)
    try:
        with open(tmp, mode) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_atomic(path: Path, data: bytes | str) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` atomically; returns ``path``."""
    with atomic_file(path, "wb") as fh:
        fh.write(data.encode() if isinstance(data, str) else data)
    return Path(path)
