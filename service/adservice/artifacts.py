"""Artifact files: written whole to a temporary name, synced, then renamed into place.

A file appears under its final name only once complete, and the database learns of it
only after that, so a half-written or crashed upload is never served. Final names carry
the content's hash: a new upload of a name never overwrites the file the database still
points at, so an upload refused at its last step (the lease lost meanwhile) leaves the
artifact as it was; the replaced file is removed once the database points elsewhere.

Artifacts come from workers, so they are served inert: an image the dashboard shows is
served inline only when its bytes are a raster image (the type decided here, never the
uploader's), anything else as a download of a type that no browser runs.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from collections.abc import AsyncIterator
from pathlib import Path

from adservice.errors import TooLargeError

IMAGE_SIGNATURES: tuple[tuple[bytes, str], ...] = (
    (b"\x89PNG\r\n\x1a\n", "image/png"),
    (b"\xff\xd8\xff", "image/jpeg"),
    (b"GIF87a", "image/gif"),
    (b"GIF89a", "image/gif"),
)
DOWNLOAD_TYPES = frozenset(
    {"application/json", "text/plain", "text/csv", "application/xml", "application/octet-stream"}
)
"""Declared types kept on a download (none of them runs script when downloaded)."""
SNIFF_BYTES = 16
INERT_HEADERS = {
    "X-Content-Type-Options": "nosniff",
    "Content-Security-Policy": "sandbox; default-src 'none'",
    "Cross-Origin-Resource-Policy": "same-origin",
}


def image_type(head: bytes) -> str | None:
    """The raster image type the first bytes show (RIFF WebP too), or None."""
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return "image/webp"
    return next((kind for signature, kind in IMAGE_SIGNATURES if head.startswith(signature)), None)


def served_type(head: bytes, declared: str) -> tuple[str, bool]:
    """``(media type, inline)`` for an artifact whose file starts with ``head``."""
    image = image_type(head)
    if image is not None:
        return image, True
    base = declared.split(";")[0].strip().lower()
    return (base if base in DOWNLOAD_TYPES else "application/octet-stream"), False


class ArtifactStore:
    def __init__(self, root: Path) -> None:
        self.root = root

    def folder_for(self, *, study_id: int, trial_id: int) -> Path:
        return self.root / str(study_id) / str(trial_id)

    @staticmethod
    def discard(path: str | Path) -> None:
        """Remove a file the database no longer points at."""
        Path(path).unlink(missing_ok=True)

    def remove_study(self, study_id: int) -> None:
        """Remove a deleted study's folder: its artifacts and any upload cut short."""
        shutil.rmtree(self.root / str(study_id), ignore_errors=True)

    async def write(
        self,
        *,
        study_id: int,
        trial_id: int,
        name: str,
        chunks: AsyncIterator[bytes],
        limit: int,
        limit_named: str | None = None,
    ) -> tuple[Path, int, str]:
        """Write an artifact's file from ``chunks``: its path, size and SHA-256. Past
        ``limit`` bytes, TooLargeError naming the limit (``limit_named``: the limit, its
        setting and what is used, as a refusal names it)."""
        folder = self.folder_for(study_id=study_id, trial_id=trial_id)
        folder.mkdir(parents=True, exist_ok=True)
        digest = hashlib.sha256()
        size = 0
        fd, temp_name = tempfile.mkstemp(dir=folder, prefix=".upload-")
        try:
            with os.fdopen(fd, "wb") as handle:
                async for chunk in chunks:
                    size += len(chunk)
                    if size > limit:
                        named = limit_named or f"the limit of {limit} bytes"
                        raise TooLargeError(f"artifact {name!r} exceeds {named}")
                    digest.update(chunk)
                    handle.write(chunk)
                handle.flush()
                os.fsync(handle.fileno())
            # Names are checked against NAME_PATTERN (no separators): this stays in folder.
            final = folder / f"{name}.{digest.hexdigest()[:16]}"
            os.replace(temp_name, final)
        except BaseException:
            Path(temp_name).unlink(missing_ok=True)
            raise
        return final, size, digest.hexdigest()
