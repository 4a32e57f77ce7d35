"""A checkpoint is read as data within a budget (issue 58): its members, and its replay
buffer's arrays, unpack to ``MAX_CHECKPOINT_BYTES`` at most all together, and every
``.npy`` header must name numbers its bytes hold, checked before any array is read
(a real DDPG model on a real PyBullet env, and checkpoints of it made hostile)."""

from __future__ import annotations

import io
import tracemalloc
import zipfile
from typing import Any

import numpy as np
import pytest

from adworker import checkpoints
from adworker.checkpoints import REPLAY_MEMBER, CheckpointError
from adworker.learners import DDPGLearner


@pytest.fixture
def model(env_of) -> Any:
    """A DDPG model with some transitions in its replay buffer."""
    env = env_of("stand-up", "arch_chain")
    made = DDPGLearner().make_model(env, steps=64, seed=0)
    made.learn(total_timesteps=40)
    yield made
    env.close()


def rewritten(checkpoint: bytes, **members: bytes) -> bytes:
    """``checkpoint`` with ``members`` replaced or added (deflated)."""
    out = io.BytesIO()
    with (
        zipfile.ZipFile(io.BytesIO(checkpoint)) as source,
        zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as target,
    ):
        for info in source.infolist():
            if info.filename not in members:
                target.writestr(info.filename, source.read(info))
        for name, data in members.items():
            target.writestr(name, data)
    return out.getvalue()


def npy_claiming(shape: tuple[int, ...], descr: str = "<f4") -> bytes:
    """An ``.npy`` whose header claims ``shape`` over 64 bytes of data."""
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        out, {"descr": descr, "fortran_order": False, "shape": shape}
    )
    return out.getvalue() + b"\0" * 64


def replay_with(checkpoint: bytes, **arrays: bytes) -> bytes:
    """The checkpoint's replay buffer with ``arrays`` (``.npy`` bytes) replaced."""
    with zipfile.ZipFile(io.BytesIO(checkpoint)) as archive:
        raw = archive.read(REPLAY_MEMBER)
    return rewritten(checkpoint, **{REPLAY_MEMBER: rewritten(raw, **arrays)})


def peak_while_loading(model: Any, checkpoint: bytes) -> tuple[int, str]:
    """The Python memory peak (bytes) while ``load_into`` refuses ``checkpoint``, and why."""
    tracemalloc.start()
    try:
        with pytest.raises(CheckpointError) as refused:
            checkpoints.load_into(model, checkpoint)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak, str(refused.value)


def test_a_checkpoint_that_fits_loads(model) -> None:
    saved = checkpoints.save(model)
    checkpoints.load_into(model, saved)
    assert model.num_timesteps == 40


def test_members_that_unpack_past_the_cap_together_are_refused_unread(model) -> None:
    """Each member under the cap, their sum over it: refused before one is read."""
    half = checkpoints.MAX_CHECKPOINT_BYTES // 2 + 1
    padded = rewritten(
        checkpoints.save(model), **{"padding-1": bytes(half), "padding-2": bytes(half)}
    )
    assert len(padded) < half // 100  # zeros: deflated to almost nothing
    peak, reason = peak_while_loading(model, padded)
    assert "the checkpoint unpacks to" in reason and "more than the limit of" in reason
    assert f"{checkpoints.MAX_CHECKPOINT_BYTES:,}" in reason
    assert peak < half // 10, peak  # neither member was unpacked


def test_a_replay_buffer_that_unpacks_past_the_cap_is_refused_unread(model) -> None:
    """Arrays of the buffer's names and kinds, each under the cap and true to its header,
    deflated inside the checkpoint (``np.savez`` stores them as they are; a hostile file
    need not): refused before either is read."""
    half = checkpoints.MAX_CHECKPOINT_BYTES // 2 + 1
    observations = model.replay_buffer.observations
    rows = half // (observations[0].nbytes) + 1
    big = io.BytesIO()
    np.save(big, np.zeros((rows, *observations.shape[1:]), dtype=observations.dtype))
    hostile = replay_with(
        checkpoints.save(model),
        **{"observations.npy": big.getvalue(), "next_observations.npy": big.getvalue()},
    )
    del big
    peak, reason = peak_while_loading(model, hostile)
    assert f"{REPLAY_MEMBER} unpacks to" in reason, reason
    assert peak < half // 10, peak


@pytest.mark.parametrize(
    ("array", "reason"),
    [
        (npy_claiming((10**11, 8)), "claims 3200000000000 bytes in 192"),
        (npy_claiming((4, 8), "|O"), "is not numbers"),
    ],
    ids=["shape-past-its-bytes", "objects"],
)
def test_a_replay_array_whose_header_lies_is_refused_before_it_is_read(
    model, array: bytes, reason: str
) -> None:
    hostile = replay_with(checkpoints.save(model), **{"observations.npy": array})
    peak, refused = peak_while_loading(model, hostile)
    assert "observations.npy" in refused and reason in refused, refused
    assert peak < 64 << 20, peak
