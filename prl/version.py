"""Code version for cache keys and run tags."""

from __future__ import annotations

import hashlib
import subprocess
from pathlib import Path

from prl.constants import REPO_ROOT

_SOURCE_DIRS = ("prl", "envs", "assets")


def code_version() -> str:
    """A digest of the library sources and assets (tracked or not), stable across checkouts."""
    h = hashlib.sha256()
    for d in _SOURCE_DIRS:
        for path in sorted((REPO_ROOT / d).rglob("*")):
            if path.is_file() and path.suffix in {".py", ".yaml", ".urdf", ".srdf"}:
                h.update(str(path.relative_to(REPO_ROOT)).encode())
                h.update(path.read_bytes())
    return h.hexdigest()[:16]


def source_version(*relative_paths: str) -> str:
    """A digest of the named source files (paths relative to the repository root), for caches that depend
    on those files alone; a missing file raises FileNotFoundError naming it."""
    h = hashlib.sha256()
    for rel in relative_paths:
        path = REPO_ROOT / rel
        if not path.is_file():
            raise FileNotFoundError(f"source file {rel!r} not found under {REPO_ROOT}")
        h.update(rel.encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def file_digest(path: str | Path) -> str:
    """SHA-256 (hex) of one file's bytes; FileNotFoundError names a missing file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"file not found: {path}")
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def git_commit() -> str:
    """The checked-out git commit, or 'unknown'."""
    try:
        res = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO_ROOT, capture_output=True, text=True,
                             timeout=10, check=False)
        return res.stdout.strip() or "unknown"
    except OSError:
        return "unknown"
