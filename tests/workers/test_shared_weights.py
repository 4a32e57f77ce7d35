"""The shared controller's weights file (``adworker.shared_weights``, issue 38): what a
worker reads from another design's upload must be named float arrays and nothing
else, refused with the reason before anything large is allocated or any code runs;
and the merge of concurrent updates."""

from __future__ import annotations

import io
import pickle
import zipfile

import numpy as np
import pytest

from adworker import shared_weights
from adworker.shared_weights import SharedWeightsError, decode, encode, merge


def archive(**members: bytes) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as zipped:
        for name, data in members.items():
            zipped.writestr(name, data)
    return out.getvalue()


def npy_claiming(shape: tuple[int, ...], descr: str = "<f8", body: bytes = b"\0" * 64) -> bytes:
    """An ``.npy`` member whose header claims ``shape`` over a few bytes of data."""
    out = io.BytesIO()
    header = {"descr": descr, "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_1_0(out, header)
    return out.getvalue() + body


def test_weights_round_trip_as_float32_and_encoding_refuses_what_decoding_would() -> None:
    weights = {"tree.joint_in.weight": np.arange(6.0).reshape(2, 3), "log_std": np.zeros(1)}
    back = decode(encode(weights))
    assert set(back) == set(weights)
    for name, array in weights.items():
        assert back[name].dtype == np.float32
        np.testing.assert_array_equal(back[name], array.astype(np.float32))
    with pytest.raises(SharedWeightsError, match="not finite"):
        encode({"a": np.array([1.0, np.inf])})


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"not a zip", "not shared-controller weights"),
        (archive(**{"a.npy": npy_claiming((2**40,))}), "claims 8796093022208 bytes"),
        (archive(**{"a.npy": npy_claiming((10, 10), "|O")}), "not numbers"),
        (archive(**{"a.npy": npy_claiming((3,), "<c16")}), "not numbers"),
        (archive(**{"a.pkl": pickle.dumps({"a": 1})}), "is not an array"),
        (archive(**{"../a.npy": npy_claiming((1,))}), "is not an array"),
        (archive(**{"a b.npy": npy_claiming((1,))}), "is not an array"),
        (archive(), "0 arrays"),
        (
            archive(**{f"a{k}.npy": npy_claiming((1,), body=b"\0" * 8) for k in range(257)}),
            "257 arrays",
        ),
        (
            archive(**{"a.npy": npy_claiming((2,), body=np.array([1.0, np.nan]).tobytes())}),
            "not finite",
        ),
    ],
    ids=[
        "not-a-zip",
        "huge-header",
        "objects",
        "complex",
        "pickle",
        "path",
        "space",
        "empty",
        "too-many",
        "nan",
    ],
)
def test_a_file_that_is_not_plain_weights_is_refused_with_the_reason(
    data: bytes, reason: str
) -> None:
    with pytest.raises(SharedWeightsError, match=reason):
        decode(data)


def test_an_archive_that_unpacks_past_the_limit_is_refused_unread(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(shared_weights, "MAX_BYTES", 1000)
    with pytest.raises(SharedWeightsError, match="larger than 1000 bytes"):
        decode(encode({"a": np.zeros(1000)}))


def test_an_update_merges_onto_the_version_that_landed_first() -> None:
    """``current + (mine - base)``: mine itself when nothing landed in between; both
    updates kept when one did; versions of other arrays refused."""
    base = {"w": np.array([1.0, 2.0])}
    mine = {"w": np.array([1.5, 2.0])}
    np.testing.assert_allclose(merge(base, base, mine)["w"], mine["w"])
    other = {"w": np.array([1.0, 3.0])}
    np.testing.assert_allclose(merge(other, base, mine)["w"], [1.5, 3.0])
    with pytest.raises(SharedWeightsError, match="different arrays"):
        merge({"v": np.zeros(2)}, base, mine)
    with pytest.raises(SharedWeightsError, match="different shapes"):
        merge({"w": np.zeros(3)}, base, mine)


def test_a_critic_only_update_keeps_its_own_actor_and_merges_the_critic() -> None:
    """``actor_of_mine``: the modular policy's actor arrays (``log_std``, ``action_net.*``
    and head 0 of the stacked tree arrays) are the update's own, whatever landed in
    between; the critic (head 1, the pooling, the value layer) merges as any update."""
    tree = "mlp_extractor.tree.joint_in.weight"
    base = {
        "log_std": np.array([5.0]),
        "action_net.linear.weight": np.array([5.0, 5.0]),
        tree: np.array([[5.0, 5.0], [5.0, 5.0]]),
        "value_net.weight": np.array([5.0, 5.0]),
        "mlp_extractor.pool.bias": np.array([5.0]),
    }
    landed = {name: value + 1.0 for name, value in base.items()}  # another design's update
    mine = {name: value * 0.0 for name, value in base.items()}  # trained from elsewhere
    merged = merge(landed, base, mine, actor_of_mine=True)
    np.testing.assert_allclose(merged["log_std"], [0.0])
    np.testing.assert_allclose(merged["action_net.linear.weight"], [0.0, 0.0])
    np.testing.assert_allclose(merged[tree], [[0.0, 0.0], [1.0, 1.0]])  # actor; critic
    np.testing.assert_allclose(merged["value_net.weight"], [1.0, 1.0])
    np.testing.assert_allclose(merged["mlp_extractor.pool.bias"], [1.0])
    # without it, everything merges: the actor is then no design's
    np.testing.assert_allclose(merge(landed, base, mine)["log_std"], [1.0])
