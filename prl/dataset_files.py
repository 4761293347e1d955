"""A dataset directory on disk: put a finished staging directory in place atomically, recover after a kill.

A writer builds the new dataset in :func:`staging_path` (a hidden sibling of the destination named
after the writing process), then :func:`move_into_place` swaps it in: ``renameat2(RENAME_EXCHANGE)``
where supported, else old-aside / new-in / old-removed, the parent directory synced afterwards. A reader
sees the old dataset or the new one. :func:`recover_stale` cleans up after a killed writer (drops its
staging directory, puts a set-aside dataset back). Single files are written with ``prl.atomic``.
"""

from __future__ import annotations

import ctypes
import errno
import hashlib
import os
import shutil
from pathlib import Path


def staging_path(root: Path) -> Path:
    """Where this process builds the replacement of ``root``: ``.<name>.staging-<pid>`` next to it."""
    return root.parent / f".{root.name}.staging-{os.getpid()}"


def check_destination(root: Path) -> None:
    """Raise unless ``root`` can be (re)placed: parent creatable and writable, root a dataset or absent."""
    if root.exists() or root.is_symlink():
        if not root.is_dir() or root.is_symlink():
            raise NotADirectoryError(f"destination {str(root)!r} exists and is not a directory")
        if any(root.iterdir()) and not (root / "meta" / "info.json").is_file():
            raise ValueError(f"destination {str(root)!r} exists, is not empty and is not a LeRobot dataset; "
                             "refusing to replace it")
    probe = root.parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise NotADirectoryError(f"destination {str(root)!r}: {str(probe)!r} is not a directory")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise PermissionError(f"destination {str(root)!r} is not writable ({str(probe)!r} denies writing)")
    try:
        root.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PermissionError(f"destination {str(root)!r} is not writable: {exc}") from exc


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def recover_stale(root: Path) -> None:
    """Clean up after a killed writer of ``root``: drop its staging dir, restore or drop a set-aside root."""
    for kind in ("staging", "old"):
        for d in root.parent.glob(f".{root.name}.{kind}-*"):
            try:
                pid = int(d.name.rsplit("-", 1)[1])
            except ValueError:
                continue
            if pid == os.getpid() or _pid_alive(pid):
                continue
            if kind == "old" and not (root / "meta" / "info.json").is_file():
                # killed between moving the old dataset aside and the new one in: put it back
                if root.is_dir() and not root.is_symlink() and not any(root.iterdir()):
                    root.rmdir()
                if not root.exists():
                    os.rename(d, root)
            else:
                shutil.rmtree(d, ignore_errors=True)


def _rename_exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False where unsupported."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP):
        return False
    raise OSError(err, f"swapping {str(a)!r} and {str(b)!r} failed: {os.strerror(err)}")


def _fsync_dir(d: Path) -> None:
    fd = os.open(d, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def move_into_place(staging: Path, root: Path) -> None:
    """Make ``staging`` the dataset at ``root``; an old dataset there is removed only once replaced."""
    if not root.exists():
        os.rename(staging, root)
    elif _rename_exchange(staging, root):
        shutil.rmtree(staging)  # now holds the old dataset
    else:
        old = root.parent / f".{root.name}.old-{os.getpid()}"
        os.rename(root, old)
        try:
            os.rename(staging, root)
        except BaseException:
            os.rename(old, root)
            raise
        shutil.rmtree(old)
    _fsync_dir(root.parent)


def tree_size(root: Path) -> int:
    """Bytes of all files under ``root``."""
    return sum(f.stat().st_size for f in Path(root).rglob("*") if f.is_file())


def dataset_digest(root: Path) -> str:
    """A short digest of a dataset's files (names and bytes), for tracking which data a run used."""
    h = hashlib.sha256()
    for path in sorted(p for p in Path(root).rglob("*") if p.is_file()):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]
