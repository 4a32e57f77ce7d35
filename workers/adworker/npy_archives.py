"""Zip archives of arrays read as data, never trusted: what they unpack to is capped in
total, and each ``.npy`` member's header is checked before its array is read (a header
may claim any shape: ``np.load`` would allocate it before finding the data missing).
Used by :mod:`adworker.checkpoints` and :mod:`adworker.shared_weights`."""

from __future__ import annotations

import math
import zipfile
from typing import IO

import numpy as np


class ArchiveError(ValueError):
    """An archive past its size limit, or a member that is not plain numbers."""


def check_total(archive: zipfile.ZipFile, limit: int, what: str) -> None:
    """``archive``'s members unpack to ``limit`` bytes at most, all together (each zip
    member's own declared size: reading one never yields more)."""
    total = sum(member.file_size for member in archive.infolist())
    if total > limit:
        raise ArchiveError(
            f"{what} unpacks to {total:,} bytes in all, more than the limit of {limit:,}"
        )


def check_npy_header(stream: IO[bytes], member: zipfile.ZipInfo, limit: int) -> None:
    """The ``.npy`` header at the start of ``stream`` (the member ``member``): numbers
    only, and no more of them than the member's bytes hold, nor than ``limit`` bytes."""
    try:
        version = np.lib.format.read_magic(stream)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(stream)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(stream)
        else:
            raise ArchiveError(f"member {member.filename!r}: .npy version {version}")
    except ArchiveError:
        raise
    except ValueError as error:
        raise ArchiveError(f"member {member.filename!r}: not an .npy header ({error})") from None
    if dtype.kind not in "fiu" or dtype.hasobject:
        raise ArchiveError(f"member {member.filename!r} is not numbers ({dtype})")
    size = dtype.itemsize * math.prod(shape)
    if size > member.file_size or size > limit:
        raise ArchiveError(f"member {member.filename!r} claims {size} bytes in {member.file_size}")


def check_npz(archive: zipfile.ZipFile, limit: int, what: str) -> None:
    """An ``.npz``: its members unpack to ``limit`` bytes at most in all, and each is an
    ``.npy`` whose header passes :func:`check_npy_header`; nothing else is read."""
    check_total(archive, limit, what)
    for member in archive.infolist():
        if not member.filename.endswith(".npy"):
            raise ArchiveError(f"{what}: member {member.filename[:100]!r} is not an array")
        with archive.open(member) as stream:
            check_npy_header(stream, member, limit)
