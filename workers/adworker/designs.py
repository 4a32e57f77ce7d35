"""Hand-made reference designs: the arch and the along-links chain, and a few trees.

Used by the tests and the benchmark to check that a task separates a design that
can do it from one that cannot, independently of any design space or decoder.
"""

from __future__ import annotations

import math

from adclient.designs import Design, Joint, Link

HALF_PI = math.pi / 2


def axis(theta: float, phi: float) -> tuple[float, float, float]:
    """The joint axis of (theta, phi), per the convention in adclient.design."""
    return (
        math.sin(theta) * math.cos(phi),
        math.sin(theta) * math.sin(phi),
        math.cos(theta),
    )


def tree_design(
    edges: list[tuple[str, str]],
    angles: dict[str, tuple[float, float]],
    *,
    length: float | dict[str, float] = 0.4,
    radius: float = 0.04,
    mass: float = 1.0,
    position: float | dict[str, float] = 1.0,
    limit: float = HALF_PI,
    effort: float = 20.0,
    velocity: float = 5.0,
    structure_index: int = 0,
) -> Design:
    """A design from its edges and, per child, the (theta, phi) of its joint."""
    children = [child for _, child in edges]
    names: list[str] = []
    for parent, child in edges:
        for name in (parent, child):
            if name not in names:
                names.append(name)
    roots = [name for name in names if name not in children]
    if len(roots) != 1:
        raise ValueError(f"edges {edges} do not form one tree")
    lengths = length if isinstance(length, dict) else dict.fromkeys(names, length)
    positions = position if isinstance(position, dict) else dict.fromkeys(children, position)
    links = [
        Link(name=name, shape="cylinder", length=lengths[name], radius=radius, mass=mass)
        for name in names
    ]
    joints = []
    for parent, child in edges:
        theta, phi = angles[child]
        joints.append(
            Joint(
                name=f"{parent}_{child}",
                parent=parent,
                child=child,
                axis=axis(theta, phi),
                axis_theta=theta,
                axis_phi=phi,
                position=positions[child],
                lower=-limit,
                upper=limit,
                effort=effort,
                velocity=velocity,
            )
        )
    return Design(structure_index=structure_index, root=roots[0], links=links, joints=joints)


def arch_chain(**kwargs: object) -> Design:
    """a-b-c with parallel axes perpendicular to the chain, horizontal when lying down."""
    angles = {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, HALF_PI)}
    return tree_design([("a", "b"), ("b", "c")], angles, **kwargs)  # type: ignore[arg-type]


def along_links_chain(**kwargs: object) -> Design:
    """a-b-c with both axes along the links: the joints only roll the cylinders."""
    angles = {"b": (0.0, 0.0), "c": (0.0, 0.0)}
    return tree_design([("a", "b"), ("b", "c")], angles, **kwargs)  # type: ignore[arg-type]


def crossed_chain(**kwargs: object) -> Design:
    """a-b-c with perpendicular axes (x then y): the arm can point anywhere."""
    angles = {"b": (HALF_PI, 0.0), "c": (HALF_PI, HALF_PI)}
    return tree_design([("a", "b"), ("b", "c")], angles, **kwargs)  # type: ignore[arg-type]


def parallel_chain(**kwargs: object) -> Design:
    """a-b-c with both axes along x: the arm moves in the y-z plane only."""
    angles = {"b": (HALF_PI, 0.0), "c": (HALF_PI, 0.0)}
    return tree_design([("a", "b"), ("b", "c")], angles, **kwargs)  # type: ignore[arg-type]
