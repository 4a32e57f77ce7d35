"""The plain one-hot encoding of multi-structure spaces (``encoding: onehot``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from adclient.decode import decode, onehot_representation, spec_layout, structure_of
from adclient.design import DesignSpace
from adclient.encode import encode
from tests.client.design_strategies import multi_structure_spaces, single_structure_spaces

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _onehot(body: dict[str, Any]) -> DesignSpace:
    return DesignSpace.model_validate({**body, "encoding": "onehot"})


@settings(max_examples=30, deadline=None)
@given(multi_structure_spaces(), st.data())
def test_onehot_round_trip_and_argmax_structure(body: dict[str, Any], data: st.DataObject) -> None:
    space = _onehot(body)
    representation = onehot_representation(space)
    layout = spec_layout(space)
    count = len(space.tree_structures())
    assert representation.kind == "onehot"
    assert representation.bounds == [[0.0] * (count + layout.size), [1.0] * (count + layout.size)]
    vector = data.draw(
        st.lists(st.floats(0.0, 1.0), min_size=count + layout.size, max_size=count + layout.size)
    )
    design = decode(space, representation, vector)
    expected = int(np.argmax(vector[:count]))
    assert design.structure_index == expected == structure_of(representation, vector)
    assert sorted(design.edges()) == sorted(space.tree_structures()[expected])
    # encode gives the one-hot of the structure and the specs the structure uses
    again = encode(space, representation, design)
    assert again[:count] == [1.0 if k == expected else 0.0 for k in range(count)]
    used = layout.used_slots(space.tree_structures()[expected])
    assert np.allclose(np.asarray(again[count:])[used], np.asarray(vector[count:])[used])
    assert decode(space, representation, again) == design


def test_onehot_needs_several_structures() -> None:
    body = yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text())["space"]
    with pytest.raises(ValueError, match="several structures"):
        onehot_representation(_onehot(body))


@settings(max_examples=10, deadline=None)
@given(single_structure_spaces())
def test_encoding_defaults_to_mixed(body: dict[str, Any]) -> None:
    assert DesignSpace.model_validate(body).encoding == "mixed"


def test_service_builds_the_encoding_the_space_names() -> None:
    representation_module = pytest.importorskip("adservice.representation")
    body = yaml.safe_load((EXAMPLES / "multi-structure.yaml").read_text())["space"]
    mixed = representation_module.build_representation(DesignSpace.model_validate(body))
    fused = representation_module.build_representation(
        DesignSpace.model_validate({**body, "encoding": "fused"})
    )
    plain = representation_module.build_representation(_onehot(body))
    single = yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text())["space"]
    assert mixed.kind == "mixed"
    assert fused.kind == "fused"
    assert plain.kind == "onehot"
    # 6 structures + 8 joint-axis specs (b..e, theta and phi each)
    assert len(plain.bounds[0]) == 6 + 8
    assert representation_module.build_representation(_onehot(single)).kind == "identity"
