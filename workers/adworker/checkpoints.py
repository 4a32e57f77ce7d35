"""A stable-baselines3 learner's checkpoint as data, never code.

SB3's own ``model.save`` cloudpickles part of its data and ``save_replay_buffer``
pickles the buffer: loading either runs whatever the file says, so a checkpoint
anyone could upload would run code on every worker that loads it. This
format holds numbers only, in one zip (``checkpoint.zip``):

- ``checkpoint.json``: the format, the algorithm, the steps trained, the updates made,
  and the observation and action shapes it was trained on;
- ``parameters.pt``: the networks' and optimisers' state dicts (``torch.save``), read
  back with ``torch.load(weights_only=True)`` (tensors and plain containers only);
- ``replay_buffer.npz`` (off-policy learners): the buffer's transitions, oldest first,
  read with ``np.load(allow_pickle=False)``.

Before anything is read, the checkpoint's members must unpack to
``MAX_CHECKPOINT_BYTES`` in all, and so must the replay buffer's arrays, each ``.npy``
header naming numbers that its bytes hold (:mod:`adworker.npy_archives`).

Loading fills a model the worker built itself from the job's own config (learner,
hyperparameters, this design's env): nothing in the file names a class, a function or
an object to make, so a file that does not fit is refused with the reason, never run.
A checkpoint of the earlier format (``model.zip`` and ``replay_buffer.pkl``) is refused
unread.
"""

from __future__ import annotations

import io
import json
import re
import zipfile
from collections.abc import Callable
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from adworker.npy_archives import ArchiveError, check_npz, check_total

FORMAT: Literal[2] = 2
META_MEMBER = "checkpoint.json"
PARAMETERS_MEMBER = "parameters.pt"
REPLAY_MEMBER = "replay_buffer.npz"
REPLAY_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")
"""A replay buffer's arrays, one row per transition (SB3's ``ReplayBuffer``)."""
MAX_CHECKPOINT_BYTES = 256 << 20
"""The most a checkpoint may unpack to, its members all together, and its replay
buffer's arrays all together (a 20,000-step SAC buffer is about 10 MB; the server's
64 MB artifact limit holds some 300,000 transitions, about 160 MB unpacked)."""


class CheckpointError(ValueError):
    """A checkpoint that is not of this format or does not fit the model it would fill."""


class _Meta(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    format: Literal[2]
    algorithm: str
    num_timesteps: int = Field(ge=0)
    n_updates: int = Field(ge=0)
    observation_shape: list[int]
    action_shape: list[int]


def save(model: Any) -> bytes:
    """``model``'s state in this format; an off-policy model's replay buffer with it,
    unless its next observations share one array with its observations
    (``optimize_memory_usage``), which this format does not keep."""
    import torch

    _, variables = model._get_torch_save_params()
    state = {
        "state_dicts": model.get_parameters(),
        "variables": {name: _attribute(model, name).detach() for name in variables},
    }
    meta = _Meta(
        format=FORMAT,
        algorithm=type(model).__name__,
        num_timesteps=int(model.num_timesteps),
        n_updates=int(getattr(model, "_n_updates", 0)),
        observation_shape=list(model.observation_space.shape),
        action_shape=list(model.action_space.shape),
    )
    with io.BytesIO() as out:
        with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as archive:
            archive.writestr(META_MEMBER, meta.model_dump_json())
            parameters = io.BytesIO()
            torch.save(state, parameters)
            archive.writestr(PARAMETERS_MEMBER, parameters.getvalue())
            replay = _replay_arrays(getattr(model, "replay_buffer", None))
            if replay is not None:
                arrays = io.BytesIO()
                np.savez(arrays, allow_pickle=False, **replay)
                archive.writestr(REPLAY_MEMBER, arrays.getvalue())
        return out.getvalue()


def load_into(model: Any, checkpoint: bytes) -> None:
    """Fill ``model`` (built for this design by the worker) with a :func:`save`d state:
    parameters, optimisers, steps trained and replay buffer. CheckpointError when it is
    of another format, algorithm or shape; nothing in it is unpickled."""
    import torch

    with zipfile.ZipFile(io.BytesIO(checkpoint)) as archive:
        _checked(check_total, archive, MAX_CHECKPOINT_BYTES, "the checkpoint")
        names = set(archive.namelist())
        if META_MEMBER not in names:
            older = " (SB3's pickles: refused unread)" if "model.zip" in names else ""
            raise CheckpointError(f"not a checkpoint of format {FORMAT}{older}")
        try:
            meta = _Meta.model_validate(json.loads(_read(archive, META_MEMBER)))
        except ValueError as error:
            raise CheckpointError(f"{META_MEMBER}: {error}") from None
        _check_fits(model, meta)
        parameters = _read(archive, PARAMETERS_MEMBER)
        try:
            state = torch.load(io.BytesIO(parameters), map_location="cpu", weights_only=True)
        except Exception as error:
            found = re.search(r"WeightsUnpickler error: (.*?)(?:\. |$)", str(error), re.M)
            raise CheckpointError(
                f"{PARAMETERS_MEMBER} is not tensors and plain data alone, refused unread "
                f"({found.group(1) if found else type(error).__name__})"
            ) from None
        _load_parameters(model, state)
        keeps_replay = _replay_arrays(getattr(model, "replay_buffer", None)) is not None
        if REPLAY_MEMBER in names and keeps_replay:
            _load_replay(model, _read(archive, REPLAY_MEMBER))
    model.num_timesteps = meta.num_timesteps
    model._n_updates = meta.n_updates


def _read(archive: zipfile.ZipFile, name: str) -> bytes:
    try:
        info = archive.getinfo(name)
    except KeyError:
        raise CheckpointError(f"the checkpoint has no {name}") from None
    return archive.read(info)


def _checked(check: Callable[..., None], *args: Any) -> None:
    """``check(*args)`` of :mod:`adworker.npy_archives`, its refusal a CheckpointError."""
    try:
        check(*args)
    except ArchiveError as error:
        raise CheckpointError(f"{error}: refused unread") from None


def _check_fits(model: Any, meta: _Meta) -> None:
    algorithm = type(model).__name__
    if meta.algorithm != algorithm:
        raise CheckpointError(f"a checkpoint of {meta.algorithm}, not of {algorithm}")
    for what, saved, space in (
        ("observation", meta.observation_shape, model.observation_space),
        ("action", meta.action_shape, model.action_space),
    ):
        if tuple(saved) != tuple(space.shape):
            raise CheckpointError(
                f"its {what} space {tuple(saved)} does not fit this design's {space.shape}"
            )


def _load_parameters(model: Any, state: Any) -> None:
    """The state dicts (the policy's first, strictly: a shape that differs is refused
    before any optimiser is touched) and the tensors SB3 keeps beside them."""
    names, variables = model._get_torch_save_params()
    if not isinstance(state, dict) or set(state) != {"state_dicts", "variables"}:
        raise CheckpointError(f"{PARAMETERS_MEMBER} is not a state of this format")
    dicts, tensors = state["state_dicts"], state["variables"]
    if not isinstance(dicts, dict) or set(dicts) != set(names):
        raise CheckpointError(f"{PARAMETERS_MEMBER} holds no state of exactly {sorted(names)}")
    if not isinstance(tensors, dict) or set(tensors) != set(variables):
        raise CheckpointError(f"{PARAMETERS_MEMBER} holds no tensors of exactly {variables}")
    try:
        model.set_parameters({name: dicts[name] for name in names}, exact_match=True)
    except (RuntimeError, TypeError, KeyError, ValueError) as error:
        raise CheckpointError(f"its parameters do not fit: {error}") from None
    for name in variables:
        target = _attribute(model, name)
        if getattr(tensors[name], "shape", None) != target.shape:
            raise CheckpointError(f"its {name} does not fit this model's")
        target.data.copy_(tensors[name])


def _replay_arrays(buffer: Any) -> dict[str, np.ndarray] | None:
    """A replay buffer's transitions, oldest first; None without one this format keeps."""
    if buffer is None or getattr(buffer, "optimize_memory_usage", True):
        return None
    arrays: dict[str, np.ndarray] = {}
    for name in REPLAY_ARRAYS:
        array = getattr(buffer, name, None)
        if not isinstance(array, np.ndarray):
            return None  # dict observations: no MlpPolicy learner has them
        arrays[name] = array
    count = buffer.buffer_size if buffer.full else buffer.pos
    start = buffer.pos if buffer.full else 0
    order = (start + np.arange(count)) % buffer.buffer_size
    return {name: array[order] for name, array in arrays.items()}


def _load_replay(model: Any, raw: bytes) -> None:
    """Saved transitions into ``model``'s buffer, grown to hold them all when it was
    built for fewer steps (a warm start's budget below its source's), as the source's
    own buffer held them."""
    try:
        with zipfile.ZipFile(io.BytesIO(raw)) as arrays_archive:
            _checked(check_npz, arrays_archive, MAX_CHECKPOINT_BYTES, REPLAY_MEMBER)
    except zipfile.BadZipFile as error:
        raise CheckpointError(f"{REPLAY_MEMBER} is not an .npz ({error})") from None
    with np.load(io.BytesIO(raw), allow_pickle=False) as saved:
        if set(saved.files) != set(REPLAY_ARRAYS):
            raise CheckpointError(f"{REPLAY_MEMBER} holds no arrays of exactly {REPLAY_ARRAYS}")
        try:
            arrays = {name: saved[name] for name in REPLAY_ARRAYS}
        except ValueError as error:  # an object array: a pickle
            raise CheckpointError(
                f"{REPLAY_MEMBER} is not plain arrays, refused unread ({error})"
            ) from None
    count = len(arrays["observations"])
    buffer = model.replay_buffer
    for name, array in arrays.items():
        target = getattr(buffer, name)
        if array.dtype != target.dtype or array.shape != (count, *target.shape[1:]):
            raise CheckpointError(
                f"its replay buffer's {name} ({array.dtype}, {array.shape}) does not fit "
                f"this model's ({target.dtype}, (n, {', '.join(map(str, target.shape[1:]))}))"
            )
    if count > buffer.buffer_size:
        model.buffer_size = count
        model.replay_buffer = buffer = type(buffer)(
            count,
            model.observation_space,
            model.action_space,
            device=model.device,
            n_envs=model.n_envs,
            optimize_memory_usage=False,
            **model.replay_buffer_kwargs,
        )
    for name, array in arrays.items():
        getattr(buffer, name)[:count] = array
    buffer.pos = count % buffer.buffer_size
    buffer.full = count == buffer.buffer_size


def _attribute(model: Any, dotted: str) -> Any:
    from stable_baselines3.common.save_util import recursive_getattr

    return recursive_getattr(model, dotted)
