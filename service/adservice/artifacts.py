"""Artifact files: written whole to a temporary name, synced, then renamed into place.

A file appears under its final name only once complete, and the database learns of it
only after that, so a half-written or crashed upload is never served.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import AsyncIterator
from pathlib import Path

from adservice.errors import TooLargeError


class ArtifactStore:
    def __init__(self, root: Path) -> None:
        self.root = root

    def path_for(self, *, study_id: int, trial_id: int, name: str) -> Path:
        # Names are validated against NAME_PATTERN (no separators), so this stays inside root.
        return self.root / str(study_id) / str(trial_id) / name

    async def write(
        self,
        *,
        study_id: int,
        trial_id: int,
        name: str,
        chunks: AsyncIterator[bytes],
        limit: int,
    ) -> tuple[Path, int, str]:
        final = self.path_for(study_id=study_id, trial_id=trial_id, name=name)
        final.parent.mkdir(parents=True, exist_ok=True)
        digest = hashlib.sha256()
        size = 0
        fd, temp_name = tempfile.mkstemp(dir=final.parent, prefix=".upload-")
        try:
            with os.fdopen(fd, "wb") as handle:
                async for chunk in chunks:
                    size += len(chunk)
                    if size > limit:
                        raise TooLargeError(f"artifact {name!r} exceeds the limit of {limit} bytes")
                    digest.update(chunk)
                    handle.write(chunk)
                handle.flush()
                os.fsync(handle.fileno())
            os.replace(temp_name, final)
        except BaseException:
            Path(temp_name).unlink(missing_ok=True)
            raise
        return final, size, digest.hexdigest()
