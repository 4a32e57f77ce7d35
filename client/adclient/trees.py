"""Tree structures over a space's instances: an edge, checking a structure, and every
tree over some names (Prüfer sequences)."""

from __future__ import annotations

import heapq
import itertools
import re
from collections.abc import Iterator
from typing import Annotated

from pydantic import Field

from adclient.specs import NAME_PATTERN

Edge = tuple[str, str]
"""(parent instance, child instance): one joint (revolute unless its kind says)."""
EdgeArray = Annotated[Edge, Field(strict=False)]
"""An edge as a study file gives it: a JSON array of two names (a strict model takes no
list for a tuple otherwise)."""


def valid_name(name: str) -> bool:
    return re.fullmatch(NAME_PATTERN, name) is not None


def check_tree(edges: list[Edge], names: set[str], where: str) -> None:
    """A structure is a rooted tree: >= 1 edge, one parent per child, one root, connected."""
    if not edges:
        raise ValueError(f"{where}: a structure needs at least one edge (two links)")
    parent_of: dict[str, str] = {}
    nodes: list[str] = []
    for number, (parent, child) in enumerate(edges):
        for name in (parent, child):
            if name not in names:
                raise ValueError(
                    f"{where}[{number}]: unknown instance {name!r} "
                    f"(instances: {', '.join(sorted(names))})"
                )
            if name not in nodes:
                nodes.append(name)
        if parent == child:
            raise ValueError(f"{where}[{number}]: edge joins {parent!r} to itself")
        if child in parent_of:
            raise ValueError(
                f"{where}: not a tree: {child!r} has two parents "
                f"({parent_of[child]!r} and {parent!r})"
            )
        parent_of[child] = parent
    roots = [name for name in nodes if name not in parent_of]
    if len(roots) != 1:
        raise ValueError(
            f"{where}: not a tree: it has no root (a cycle)"
            if not roots
            else f"{where}: not a tree: several roots ({', '.join(map(repr, roots))}), "
            "so it is not connected"
        )
    for start in parent_of:
        seen = {start}
        node = start
        while node in parent_of:
            node = parent_of[node]
            if node in seen:
                raise ValueError(f"{where}: not a tree: a cycle through {node!r}")
            seen.add(node)


def all_trees(names: list[str]) -> Iterator[list[Edge]]:
    """Every labelled tree over ``names`` (Pruefer sequences in lexicographic order),
    rooted at ``names[0]``, edges listed breadth-first with children in name order."""
    n = len(names)
    if n == 2:
        yield [(names[0], names[1])]
        return
    for sequence in itertools.product(range(n), repeat=n - 2):
        adjacency: list[list[int]] = [[] for _ in range(n)]
        for u, v in pruefer_edges(list(sequence), n):
            adjacency[u].append(v)
            adjacency[v].append(u)
        edges: list[Edge] = []
        visited = {0}
        frontier = [0]
        while frontier:
            following: list[int] = []
            for node in frontier:
                for neighbour in sorted(adjacency[node]):
                    if neighbour not in visited:
                        visited.add(neighbour)
                        edges.append((names[node], names[neighbour]))
                        following.append(neighbour)
            frontier = following
        yield edges


def pruefer_edges(sequence: list[int], n: int) -> list[tuple[int, int]]:
    degree = [1] * n
    for node in sequence:
        degree[node] += 1
    leaves = [node for node in range(n) if degree[node] == 1]
    heapq.heapify(leaves)
    edges: list[tuple[int, int]] = []
    for node in sequence:
        leaf = heapq.heappop(leaves)
        edges.append((leaf, node))
        degree[node] -= 1
        if degree[node] == 1:
            heapq.heappush(leaves, node)
    u, v = heapq.heappop(leaves), heapq.heappop(leaves)
    edges.append((u, v))
    return edges
