"""The shared controller's weights as data (``task.transfer: shared``): named float32
arrays in one ``.npz``, read with ``np.load(allow_pickle=False)`` after its members
are checked, and the rule that merges concurrent updates.

A version of a study's shared controller is one such file, uploaded by the worker
whose design trained it as an artifact of its trial. Names, member count, sizes and
values are whitelisted before anything is unpacked, so a file a user uploads can
neither run code nor blow up a worker's memory. Merging needs no network: a design
started from weights ``base`` and ended at ``mine``; if the study's current version
moved on meanwhile (another design's update landed first), its update is
``current + (mine - base)``: the other design's update is kept and this one's is
added (docs/worker.md, "A shared controller").
"""

from __future__ import annotations

import io
import re
import zipfile
from collections.abc import Mapping
from typing import IO

import numpy as np

from adclient.schemas import SHARED_ARTIFACT
from adworker.npy_archives import ArchiveError, check_npy_header

Weights = dict[str, np.ndarray]

__all__ = ["SHARED_ARTIFACT", "SharedWeightsError", "Weights", "decode", "encode", "merge"]

MAX_ARRAYS = 256
MAX_BYTES = 64 << 20
"""The most a file's arrays may unpack to, all together (the built-in modular policy is
well under 1 MB)."""
_NAME = re.compile(r"[A-Za-z0-9_.]{1,100}")


class SharedWeightsError(ValueError):
    """A file that is not shared-controller weights, or weights that do not fit."""


def encode(weights: Mapping[str, np.ndarray]) -> bytes:
    """``weights`` as this format (float32, deflated)."""
    checked = _checked({name: np.asarray(array) for name, array in weights.items()})
    with io.BytesIO() as out:
        np.savez_compressed(out, **checked)  # type: ignore[arg-type]
        return out.getvalue()


def decode(data: bytes) -> Weights:
    """The weights in ``data``; :class:`SharedWeightsError` naming what is wrong."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            members = archive.infolist()
            if not members or len(members) > MAX_ARRAYS:
                raise SharedWeightsError(f"{len(members)} arrays (1 to {MAX_ARRAYS} allowed)")
            if sum(member.file_size for member in members) > MAX_BYTES:
                raise SharedWeightsError(f"arrays larger than {MAX_BYTES} bytes unpacked")
            for member in members:
                if not member.filename.endswith(".npy") or not _NAME.fullmatch(
                    member.filename[:-4]
                ):
                    raise SharedWeightsError(f"member {member.filename[:100]!r} is not an array")
                with archive.open(member) as stream:
                    _check_header(stream, member)
        with np.load(io.BytesIO(data), allow_pickle=False) as archive:
            weights = {name: archive[name] for name in archive.files}
    except SharedWeightsError:
        raise
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, MemoryError) as error:
        raise SharedWeightsError(f"not shared-controller weights: {error}") from error
    return _checked(weights)


def _check_header(stream: IO[bytes], member: zipfile.ZipInfo) -> None:
    try:
        check_npy_header(stream, member, MAX_BYTES)
    except ArchiveError as error:
        raise SharedWeightsError(str(error)) from None


ACTOR_ARRAYS = ("log_std", "action_net.")
"""The built-in modular policy's (:mod:`adworker.modular`) arrays of the actor alone;
beside them the actor is head 0 of the stacked ``STACKED_ARRAYS``, and the rest (the
critic's head 1, its pooling and value layer) is the critic's."""
STACKED_ARRAYS = "mlp_extractor.tree."
"""The modular policy's tree network: arrays stacked ``[actor, critic]``."""


def actor_part(name: str, array: np.ndarray) -> np.ndarray | None:
    """The actor's part of a modular policy's array ``name`` (a view), None if it has
    none."""
    if name.startswith(STACKED_ARRAYS):
        return array[0]
    if name.startswith(ACTOR_ARRAYS):
        return array
    return None


def merge(
    current: Mapping[str, np.ndarray],
    base: Mapping[str, np.ndarray],
    mine: Mapping[str, np.ndarray],
    *,
    actor_of_mine: bool = False,
) -> Weights:
    """``current + (mine - base)``: an update trained from ``base`` applied onto the
    study's ``current`` version (equal to ``mine`` when ``current`` is ``base``).
    ``actor_of_mine``: the actor (``actor_part``) is ``mine``'s, only the critic merged:
    a design that carried the critic alone (``shared_carries: critic``) trained its actor
    from the initial weights, so its actor is no change to anyone's."""
    if not (set(current) == set(base) == set(mine)):
        raise SharedWeightsError("the versions name different arrays")
    merged = {}
    for name in sorted(mine):
        if not (current[name].shape == base[name].shape == mine[name].shape):
            raise SharedWeightsError(f"array {name!r} has different shapes in the versions")
        merged[name] = (current[name] + (mine[name] - base[name])).astype(np.float32)
        actor = actor_part(name, merged[name]) if actor_of_mine else None
        if actor is not None:
            actor[...] = actor_part(name, np.asarray(mine[name], dtype=np.float32))
    return _checked(merged)


def _checked(weights: Mapping[str, np.ndarray]) -> Weights:
    out: Weights = {}
    if not weights or len(weights) > MAX_ARRAYS:
        raise SharedWeightsError(f"{len(weights)} arrays (1 to {MAX_ARRAYS} allowed)")
    for name, array in weights.items():
        if not _NAME.fullmatch(name):
            raise SharedWeightsError(f"array name {name[:100]!r} is not allowed")
        if array.dtype.kind not in "fiu":
            raise SharedWeightsError(f"array {name!r} is not numbers ({array.dtype})")
        values = array.astype(np.float32)
        if not np.isfinite(values).all():
            raise SharedWeightsError(f"array {name!r} holds values that are not finite")
        out[name] = values
    return out
