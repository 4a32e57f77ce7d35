"""A worker's temporary folder, and the removal of those its worker left when it died:
a folder is live while its lock file is locked (flock), which ends with the process
however it ends."""

from __future__ import annotations

import fcntl
import logging
import os
import shutil
import tempfile
from pathlib import Path

log = logging.getLogger("adworker")

WORKDIR_PREFIX = "adworker-"
WORKDIR_LOCK = ".lock"
"""In a worker's temporary folder: a file locked (flock) while the worker lives."""


def make_workdir(*, lock: bool = True) -> tuple[Path, int | None]:
    """A new temporary folder ``adworker-*`` and, with ``lock``, the descriptor of its
    lock file, locked (flock) until closed or the process ends, however it ends: what
    tells a live worker's folder from an abandoned one. The lock is taken before the
    file has its name, so no folder is ever seen with an unlocked lock of a live
    worker."""
    path = Path(tempfile.mkdtemp(prefix=WORKDIR_PREFIX))
    if not lock:
        return path, None
    staging = path / f"{WORKDIR_LOCK}.new"
    descriptor = os.open(staging, os.O_CREAT | os.O_RDWR, 0o600)
    fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    os.rename(staging, path / WORKDIR_LOCK)
    return path, descriptor


def remove_abandoned_workdirs() -> list[Path]:
    """Remove the temporary folders of this machine's workers that died without
    cleaning up (SIGKILL, the out-of-memory killer): those whose lock file no process
    holds. Folders without one (being made, kept with ``--keep-files``, or another
    program's) are left alone. Returns what it removed (logged)."""
    removed = []
    for path in Path(tempfile.gettempdir()).glob(f"{WORKDIR_PREFIX}*"):
        try:
            descriptor = os.open(path / WORKDIR_LOCK, os.O_RDWR)
        except OSError:
            continue
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            continue  # its worker is alive
        else:
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
        finally:
            os.close(descriptor)
    if removed:
        names = ", ".join(path.name for path in removed)
        log.info("removed the folders of workers that died: %s", names)
    return removed
