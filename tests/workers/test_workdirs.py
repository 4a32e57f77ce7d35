"""A worker's temporary folder is removed after its worker died, however far it got in
making it; a live worker's folder, or one just being made, is kept (real files, real
flock locks)."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from adworker.workdirs import STAGING_GRACE, WORKDIR_LOCK, remove_abandoned_workdirs


def _folder(root: Path, name: str, lock_name: str, *, age: float = 0.0) -> Path:
    path = root / f"adworker-{name}"
    path.mkdir()
    lock = path / lock_name
    lock.touch()
    if age:
        stamp = lock.stat().st_mtime - age
        os.utime(lock, (stamp, stamp))
    return path


def test_folders_of_dead_workers_go_and_live_ones_stay(tmp_path: Path) -> None:

    dead = _folder(tmp_path, "dead", WORKDIR_LOCK)
    died_making = _folder(tmp_path, "making", f"{WORKDIR_LOCK}.new", age=2 * STAGING_GRACE)
    being_made = _folder(tmp_path, "new", f"{WORKDIR_LOCK}.new")
    live = _folder(tmp_path, "live", WORKDIR_LOCK)
    live_making = _folder(tmp_path, "live-making", f"{WORKDIR_LOCK}.new", age=2 * STAGING_GRACE)
    kept = tmp_path / "adworker-kept"  # --keep-files: no lock file
    kept.mkdir()
    holders = [
        os.open(live / WORKDIR_LOCK, os.O_RDWR),
        os.open(live_making / f"{WORKDIR_LOCK}.new", os.O_RDWR),
    ]
    try:
        for holder in holders:
            fcntl.flock(holder, fcntl.LOCK_EX | fcntl.LOCK_NB)
        removed = remove_abandoned_workdirs(tmp_path)
    finally:
        for holder in holders:
            os.close(holder)
    assert sorted(removed) == sorted([dead, died_making])
    assert not dead.exists() and not died_making.exists()
    assert being_made.exists() and live.exists() and live_making.exists() and kept.exists()
