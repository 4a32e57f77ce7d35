"""Hypothesis strategies for design spaces and trees (shared by client and service tests)."""

from __future__ import annotations

import math
import sys
from typing import Any

from hypothesis import strategies as st

from adclient.specs import JOINT_SPECS, MASS_SPECS, PART_SPECS
from adclient.trees import pruefer_edges

NAMES = ["a", "b", "c", "d", "e", "f"]

SPEC_RANGES: dict[str, tuple[float, float]] = {
    "length": (0.1, 0.8),
    "radius": (0.01, 0.08),
    "mass": (0.2, 3.0),
    "density": (100.0, 8000.0),
    "axis_theta": (0.0, math.pi),
    "axis_phi": (0.0, math.pi),
    "position": (0.0, 1.0),
    "lower": (-3.0, -0.1),
    "upper": (0.1, 3.0),
    "effort": (1.0, 50.0),
    "velocity": (0.5, 10.0),
    "offset_roll": (-math.pi, math.pi),
    "offset_pitch": (-math.pi, math.pi),
    "offset_yaw": (-math.pi, math.pi),
}


@st.composite
def trees(draw: st.DrawFn, names: list[str]) -> list[tuple[str, str]]:
    """A random labelled tree over ``names``, rooted at a random one, edges shuffled."""
    n = len(names)
    if n == 2:
        edges = [(0, 1)]
    else:
        sequence = draw(st.lists(st.integers(0, n - 1), min_size=n - 2, max_size=n - 2))
        edges = pruefer_edges(sequence, n)
    root = draw(st.integers(0, n - 1))
    adjacency: dict[int, list[int]] = {node: [] for node in range(n)}
    for u, v in edges:
        adjacency[u].append(v)
        adjacency[v].append(u)
    directed: list[tuple[str, str]] = []
    seen, stack = {root}, [root]
    while stack:
        node = stack.pop()
        for other in adjacency[node]:
            if other not in seen:
                seen.add(other)
                directed.append((names[node], names[other]))
                stack.append(other)
    return draw(st.permutations(directed))


@st.composite
def spec_values(draw: st.DrawFn, spec: str, *, free: bool | None = None) -> Any:
    """A fixed number or a {low, high} bound inside the spec's sensible range; a bound
    above 0 is log-scaled half the time."""
    low, high = SPEC_RANGES[spec]
    if free is None:
        free = draw(st.booleans())
    if not free:
        return draw(st.floats(low, high))
    a = draw(st.floats(low, high))
    b = draw(st.floats(low, high))
    if abs(a - b) < 1e-3 * (high - low):
        a, b = low, high
    bound: dict[str, Any] = {"low": min(a, b), "high": max(a, b)}
    if bound["low"] >= sys.float_info.min and draw(st.booleans()):
        bound["log"] = True
    return bound


@st.composite
def single_structure_spaces(draw: st.DrawFn, max_links: int = 5) -> dict[str, Any]:
    """A single-structure design space body with at least one free spec."""
    n = draw(st.integers(2, max_links))
    names = NAMES[:n]
    n_parts = draw(st.integers(1, 2))
    parts = {}
    for index in range(n_parts):
        given = draw(st.sampled_from(MASS_SPECS))  # a link's mass, or its density
        parts[f"part{index}"] = {
            "shape": draw(st.sampled_from(["cylinder", "box"])),
            **{
                spec: draw(spec_values(spec))
                for spec in PART_SPECS
                if spec not in MASS_SPECS or spec == given
            },
        }
    joint = {
        spec: draw(spec_values(spec)) for spec in JOINT_SPECS if spec not in ("lower", "upper")
    }
    joint["lower"] = draw(spec_values("lower"))
    joint["upper"] = draw(spec_values("upper"))
    joint["axis_theta"] = draw(spec_values("axis_theta", free=True))
    instances = []
    for name in names:
        instance: dict[str, Any] = {"name": name, "part": draw(st.sampled_from(sorted(parts)))}
        if draw(st.booleans()):
            spec = draw(st.sampled_from(PART_SPECS))
            instance["overrides"] = {spec: draw(spec_values(spec))}
        if draw(st.booleans()):
            spec = draw(st.sampled_from(["axis_phi", "position", "effort"]))
            instance["joint_overrides"] = {spec: draw(spec_values(spec))}
        instances.append(instance)
    structure = draw(trees(names))
    return {
        "type": "design",
        "parts": parts,
        "joint": joint,
        "instances": instances,
        "structures": [[list(edge) for edge in structure]],
    }


@st.composite
def multi_structure_spaces(draw: st.DrawFn) -> dict[str, Any]:
    """A design space body with 2 to 5 candidate trees over subsets of up to 5 instances."""
    names = NAMES[:5]
    count = draw(st.integers(2, 5))
    structures: list[list[tuple[str, str]]] = []
    keys: set[frozenset[tuple[str, str]]] = set()
    for _ in range(count * 3):
        size = draw(st.integers(2, 5))
        tree = draw(trees(names[:size]))
        if frozenset(tree) not in keys:
            keys.add(frozenset(tree))
            structures.append(tree)
        if len(structures) == count:
            break
    used = {name for tree in structures for edge in tree for name in edge}
    if len(structures) < 2:
        structures.append([("a", "b")] if ("a", "b") not in structures[0] else [("b", "a")])
        used |= {"a", "b"}
    return {
        "type": "design",
        "parts": {
            "link": {"length": {"low": 0.2, "high": 0.6}, "radius": 0.04, "mass": 1.0},
            "limb": {"length": 0.3, "radius": 0.03, "mass": 0.5},
        },
        "instances": [
            {"name": name, "part": "link" if name in "ab" else "limb"}
            for name in names
            if name in used
        ],
        "structures": [[list(edge) for edge in tree] for tree in structures],
        "reference_per_structure": draw(st.sampled_from([4, 8, 16])),
        "fusion_solver": draw(st.sampled_from(["osqp", "exact"])),
        "fusion_margin": draw(st.sampled_from([0.0, 0.1])),
    }
