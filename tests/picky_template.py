"""A template that passes a study's creation checks and still fails some trials: it
expands at n = 0, 2 and 4 (the low, middle and high the server checks) and never at 1
or 3 (a division by zero). Shared by the service's and the worker's template tests."""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree

JOINTED = (
    '<link name="arm"><visual><geometry><box size="0.1 0.1 0.1"/></geometry></visual></link>'
    '<joint name="j" type="revolute"><parent link="base"/><child link="arm"/>'
    '<axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
)
"""An arm on a revolute joint to the link ``base``: what makes a robot a worker can drive."""
PICKY = (
    '<robot name="picky" xmlns:xacro="http://www.ros.org/wiki/xacro">'
    '<link name="base"><visual><geometry>'
    '<box size="${0.1 + 0.01 / ((n - 1) * (n - 3))} 0.1 0.1"/>'
    f"</geometry></visual></link>{JOINTED}</robot>"
)
PICKY_SPACE = {
    "type": "template",
    "template": PICKY,
    "params": [{"name": "n", "type": "int", "low": 0, "high": 4}],
}


def picky_size(n: int) -> float:
    """The base box's size at ``n`` (where it expands)."""
    return 0.1 + 0.01 / ((n - 1) * (n - 3))


def base_size(urdf: str) -> float:
    box = ElementTree.fromstring(urdf).find("link[@name='base']/visual/geometry/box")
    assert box is not None, urdf
    return float(box.get("size", "").split()[0])
