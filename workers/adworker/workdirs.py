"""A worker's temporary folder, and the removal of those its worker left when it died:
a folder is live while its lock file is locked (flock), which ends with the process
however it ends."""

from __future__ import annotations

import fcntl
import logging
import os
import shutil
import tempfile
import time
from pathlib import Path

log = logging.getLogger("adworker")

WORKDIR_PREFIX = "adworker-"
WORKDIR_LOCK = ".lock"
"""In a worker's temporary folder: a file locked (flock) while the worker lives."""
STAGING_GRACE = 60.0
"""Seconds after which a folder still holding only its unlocked staging lock file
(``.lock.new``: its worker died while making it) counts as abandoned; a live worker
locks that file the moment it creates it."""


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


def remove_abandoned_workdirs(root: Path | None = None) -> list[Path]:
    """Remove the temporary folders of this machine's workers (in ``root``, by default
    the temporary folder) that died without cleaning up (SIGKILL, the out-of-memory
    killer): those whose lock file no process holds, and those whose worker died while
    making them (a staging lock file older than ``STAGING_GRACE`` that no process
    holds). Folders without either (kept with ``--keep-files``, or another program's)
    and those being made are left alone. Returns what it removed (logged)."""
    removed = []
    for path in Path(root or tempfile.gettempdir()).glob(f"{WORKDIR_PREFIX}*"):
        lock = path / WORKDIR_LOCK
        staging = path / f"{WORKDIR_LOCK}.new"
        if not lock.exists():
            try:
                if time.time() - staging.stat().st_mtime < STAGING_GRACE:
                    continue
            except OSError:
                continue
            lock = staging
        try:
            descriptor = os.open(lock, os.O_RDWR)
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
