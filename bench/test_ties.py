"""bench/ties.py's untied arm: the quadruped with every tie removed searches each leg on
its own (24 dimensions against the tied robot's 6)."""

from __future__ import annotations

import yaml

from adclient.design import DesignSpace
from bench.ties import EXAMPLE, untied


def test_the_tied_quadruped_searches_a_quarter_of_the_untied_dimensions() -> None:
    space = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))["space"]
    tied = DesignSpace.model_validate(space)
    free = DesignSpace.model_validate(untied(space))
    assert len(tied.ties()) == 6 and free.ties() == {}
    assert len(tied.free_specs()) == 6
    assert len(free.free_specs()) == 24
    names = [instance["name"] for instance in space["instances"]]
    assert [instance.name for instance in free.instances] == names
