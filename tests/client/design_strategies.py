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


SHAPES = ["cylinder", "box", "capsule"]
JOINT_KINDS = ["revolute", "continuous", "prismatic", "fixed"]
MOTORS = {
    "small": {"effort": 2.0, "velocity": 8.0, "mass": 0.05, "cost": 10.0},
    "mid": {"effort": 6.0, "velocity": 5.0, "mass": 0.1, "cost": 25.0},
    "large": {"effort": 20.0, "velocity": 2.0, "mass": 0.3, "cost": 90.0},
}
"""Joint components: their effort and velocity set the joint's specs."""
TUBES = {
    "mass": {
        "thin": {"radius": 0.01, "mass": 0.2, "cost": 3.0},
        "thick": {"radius": 0.03, "mass": 0.9, "cost": 8.0},
    },
    "density": {
        "plastic": {"radius": 0.02, "density": 1200.0},
        "steel": {"radius": 0.015, "density": 7800.0},
        "wood": {"radius": 0.04, "density": 600.0},
    },
}
"""Part components by the spec that gives a part's mass: radius and it set the link's."""
LIMITED_MOTORS = {
    "narrow": {"effort": 4.0, "lower": -0.5, "upper": 0.5},
    "wide": {"effort": 12.0, "lower": -2.0, "upper": 2.0},
}
"""Joint components that set the limits too (a continuous joint's are placeholders)."""


@st.composite
def any_spaces(draw: st.DrawFn) -> dict[str, Any]:
    """A design space body from every feature the model has: trees (one, several, or
    all), ties (to any instance, the root included, mirrored, chained, cyclic), part
    and joint catalogues, joint kinds shared and per instance, overrides, offsets, log
    bounds, shapes, masses and densities, spec constraints and every encoding. Many are
    invalid; the server must refuse those cleanly and serve every other."""
    n = draw(st.integers(2, 5))
    names = NAMES[:n]
    catalogues: dict[str, Any] = {}
    parts: dict[str, Any] = {}
    for index in range(draw(st.integers(1, 2))):
        given = draw(st.sampled_from(MASS_SPECS))
        part: dict[str, Any] = {
            "shape": draw(st.sampled_from(SHAPES)),
            **{
                spec: draw(spec_values(spec))
                for spec in PART_SPECS
                if spec not in MASS_SPECS or spec == given
            },
        }
        if draw(st.integers(0, 3)) == 0:
            catalogues[f"{given}_tubes"] = TUBES[given]
            part["choose"] = f"{given}_tubes"
        parts[f"part{index}"] = part
    joint: dict[str, Any] = {
        spec: draw(spec_values(spec))
        for spec in draw(st.sets(st.sampled_from(JOINT_SPECS)))
        if spec not in ("lower", "upper")
    }
    joint["type"] = draw(st.sampled_from(JOINT_KINDS))
    if draw(st.booleans()):
        name, catalogue = draw(st.sampled_from([("motors", MOTORS), ("limits", LIMITED_MOTORS)]))
        catalogues[name] = catalogue
        joint["choose"] = name
    instances = [
        draw(_instances(name, names[:index], names, sorted(parts)))
        for index, name in enumerate(names)
    ]
    structures = draw(_structures(names))
    constraints = draw(st.lists(_spec_constraints(names, structures), max_size=2))
    linear = bool(constraints) and draw(st.integers(0, 4)) > 0  # fused takes none
    body: dict[str, Any] = {
        "type": "design",
        "parts": parts,
        "joint": joint,
        "instances": instances,
        "structures": structures,
        "encoding": draw(st.sampled_from(["mixed", "onehot", *([] if linear else ["fused"])])),
        "reference_per_structure": draw(st.sampled_from([2, 4])),
        "spec_constraints": constraints,
    }
    if catalogues:
        body["catalogues"] = catalogues
    return body


@st.composite
def _instances(
    draw: st.DrawFn, name: str, earlier: list[str], names: list[str], parts: list[str]
) -> dict[str, Any]:
    """One instance: tied (same_as an earlier instance, or now and then any, itself
    included: a cycle; maybe mirrored, maybe sitting elsewhere on its parent) a third of
    the time, else of a part, with overrides and a joint kind of its own now and then."""
    instance: dict[str, Any] = {"name": name}
    # hypothesis often draws every choice as its least: that path makes no cycle
    if draw(st.integers(0, 2)) == 2 and (earlier or draw(st.integers(0, 19)) == 19):
        targets = earlier if earlier and draw(st.integers(0, 19)) < 19 else names
        instance["same_as"] = draw(st.sampled_from(targets))
        if draw(st.booleans()):
            instance["mirror"] = draw(st.sampled_from(["x", "y"]))
        if draw(st.integers(0, 3)) == 0:
            instance["joint_overrides"] = {"position": draw(spec_values("position"))}
        return instance
    instance["part"] = draw(st.sampled_from(parts))
    if draw(st.integers(0, 2)) == 0:
        spec = draw(st.sampled_from(PART_SPECS))
        instance["overrides"] = {spec: draw(spec_values(spec))}
    if draw(st.integers(0, 2)) == 0:
        spec = draw(st.sampled_from(JOINT_SPECS))
        instance["joint_overrides"] = {spec: draw(spec_values(spec))}
    if draw(st.integers(0, 2)) == 0:
        instance["joint_type"] = draw(st.sampled_from(JOINT_KINDS))
    return instance


@st.composite
def _structures(draw: st.DrawFn, names: list[str]) -> Any:
    """``all`` (up to 4 instances), or one to three trees: the first over every
    instance, the others over any two or more of them (the root anywhere)."""
    if len(names) <= 4 and draw(st.integers(0, 3)) == 0:
        return "all"
    structures = [draw(trees(names))]
    for _ in range(draw(st.integers(0, 2))):
        some = draw(st.lists(st.sampled_from(names), min_size=2, max_size=len(names), unique=True))
        structures.append(draw(trees(some)))
    return [[list(edge) for edge in edges] for edges in structures]


@st.composite
def _spec_constraints(draw: st.DrawFn, names: list[str], structures: Any) -> dict[str, Any]:
    """A budget on one to three specs, mostly of instances every structure has (joint
    specs of ones each has as a child), its bound the terms' total at the middle of
    their sensible ranges, give or take: often satisfiable, not always."""
    trees = [[(names[0], name) for name in names[1:]]] if structures == "all" else structures
    links = set.intersection(*({name for edge in tree for name in edge} for tree in trees))
    children = set.intersection(*({child for _, child in tree} for tree in trees))
    if draw(st.integers(0, 4)) == 0 or not links:
        links = children = set(names)
    specs = [
        *((name, spec) for name in sorted(links) for spec in PART_SPECS),
        *((name, f"joint.{spec}") for name in sorted(children) for spec in JOINT_SPECS),
    ]
    keys = draw(st.lists(st.sampled_from(specs).map(".".join), min_size=1, max_size=3, unique=True))
    terms = {key: draw(st.sampled_from([-2.0, -1.0, 1.0, 2.0])) for key in keys}
    middle = sum(
        coefficient * sum(SPEC_RANGES[key.split(".")[-1]]) / 2 for key, coefficient in terms.items()
    )
    op = draw(st.sampled_from(["<=", ">="]))
    slack = draw(st.floats(-0.2, 1.0)) * (1.0 if op == "<=" else -1.0)
    return {"terms": terms, "op": op, "bound": middle + slack * max(1.0, abs(middle))}
