"""Search representations of design spaces (docs/method.md, "Representations"): reference
designs, their fused distances (``adservice.fusion``), MDS, and what the proposer needs
to model a vector.

``build_representation`` gives a multi-structure space the ``mixed`` representation
by default (docs/method.md, "The mixed encoding"): specs are searched in their own normalised
coordinates beside a structure index, and the fusion only places the structures.
The structures' distance is the energy distance between their reference designs
under the fused distances, sqrt(2 E f(a, b) - E f(a, a') - E f(b, b')) (zero only for
identical clouds), floored at ``STRUCTURE_DISTANCE_FLOOR`` of the largest so that no
two structures coincide (a structure kernel on coincident points could not reach
its one-hot limit), and embedded by classical MDS with every positive dimension.

For the preprint's ``fused`` encoding, ``build_representation`` embeds the fused
distances of the reference designs themselves by classical MDS and fits the decoder
tables (see ``adclient.decode``). The embedding keeps the leading
positive eigenvalues holding ``embedding_mass`` of the positive mass, at most
``embedding_max_dim`` of them. Fused distances are far from Euclidean (pooled ties
spread the spectrum), and without a cap "nearly all of the mass" means nearly one
dimension per reference design, far too many for the GP. The default cap is the free
specs plus min(structures - 1, 8): a spec vector and a structure label fit losslessly
in specs + structures - 1 dimensions, and beyond 8 structure dimensions the GP pays
more than decoding gains (over all 125 trees of 5 links, 21 dimensions still reach
every structure from random vectors, and a reference's nearest other reference has
its structure 84% of the time, against 99% with all 137).
"""

from __future__ import annotations

import math
import time
import warnings
from typing import Any

import numpy as np
from scipy.spatial.distance import pdist, squareform
from scipy.stats import qmc
from threadpoolctl import threadpool_limits

from adclient.catalogues import coordinate
from adclient.decode import (
    PAD,
    SpecLayout,
    identity_representation,
    mixed_bounds,
    onehot_representation,
    spec_layout,
)
from adclient.design import DesignSpace
from adclient.designs import Representation
from adclient.similarity import similarity_matrix
from adclient.specs import Bound
from adservice.fusion import fuse
from adservice.proposers.base import AxisColumns, ChoiceColumns, SearchStructure

MAX_REFERENCES = 512
"""Reference designs are capped near this count (at least 2 per structure)."""
MAX_STRUCTURE_DIMS = 8
"""Embedding dimensions granted to telling structures apart, by default (see above)."""
STRUCTURE_DISTANCE_FLOOR = 0.05
"""Smallest distance between two structures of a mixed representation, as a fraction
of the largest."""


# -- embedding and the decoder tables ----------------------------------------------


def classical_mds(
    F: np.ndarray, mass: float = 0.99, max_dim: int | None = None
) -> tuple[np.ndarray, dict[str, float | int]]:
    """Coordinates whose distances approximate F, from the leading positive eigenvalues
    holding ``mass`` of the positive eigenvalue mass, at most ``max_dim`` of them;
    eigenvector signs fixed so the answer is reproducible."""
    count = F.shape[0]
    squared = F**2
    centred = squared - squared.mean(axis=0) - squared.mean(axis=1)[:, None] + squared.mean()
    B = -0.5 * centred
    with threadpool_limits(limits=1):  # a few hundred rows: threads only contend
        eigenvalues, eigenvectors = np.linalg.eigh(B)
    order = np.argsort(eigenvalues)[::-1]
    eigenvalues, eigenvectors = eigenvalues[order], eigenvectors[:, order]
    positive = eigenvalues > 1e-12 * max(float(eigenvalues[0]), 1e-300)
    positive_mass = float(eigenvalues[positive].sum())
    negative_mass = float(-eigenvalues[eigenvalues < 0].sum())
    if positive_mass <= 0:
        coords = np.zeros((count, 1))
        return coords, {"embedding_dim": 1, "embedding_mass_kept": 1.0}
    cumulative = np.cumsum(eigenvalues[positive]) / positive_mass
    dim = int(np.searchsorted(cumulative, mass - 1e-12) + 1)
    dim = min(dim, int(positive.sum()), max_dim or dim)
    vectors = eigenvectors[:, :dim]
    signs = np.sign(vectors[np.argmax(np.abs(vectors), axis=0), np.arange(dim)])
    coords = vectors * signs * np.sqrt(eigenvalues[:dim])
    return coords, {
        "embedding_dim": dim,
        "embedding_mass_kept": float(cumulative[dim - 1]),
        "embedding_negative_mass": negative_mass / (positive_mass + negative_mass),
    }


def reference_specs(space: DesignSpace) -> tuple[np.ndarray, np.ndarray]:
    """Normalised spec vectors of the reference designs and their structure indices.

    Per structure a scrambled Sobol set over the slots it uses (seeded by the space's
    reference_seed and the structure index), the other slots padded; a structure with
    no free slot of its own gets one reference. Capped near MAX_REFERENCES in all.
    The points are the [0, 1] slots the proposers search, so a log spec's references
    are spread log-uniformly, as its proposals are.
    """
    layout = spec_layout(space)
    structures = layout.structures
    per_structure = min(
        space.reference_per_structure, max(2, MAX_REFERENCES // max(len(structures), 1))
    )
    blocks, labels = [], []
    for index, structure in enumerate(structures):
        used = layout.used_slots(structure)
        count = per_structure if used.any() else 1
        block = np.full((count, layout.size), PAD)
        if used.any():
            sampler = qmc.Sobol(
                int(used.sum()),
                scramble=True,
                rng=np.random.default_rng([space.reference_seed, index]),
            )
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # counts not a power of two
                block[:, used] = sampler.random(count)
        blocks.append(block)
        labels.append(np.full(count, index))
    return np.vstack(blocks), np.concatenate(labels)


def fused_references(space: DesignSpace) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """The reference designs' fused distances (M x M), their structure indices, and
    the diagnostics of the fusion.

    The spec distances are Euclidean between normalised spec vectors, so a log spec
    (``{low, high, log: true}``) is compared on its log scale: 0.01 is as far from 0.1
    as 0.1 from 1, as the proposer's model sees them, not by its physical difference."""
    layout = spec_layout(space)
    structures = layout.structures
    started = time.perf_counter()
    X, labels = reference_specs(space)
    part_of = {instance.name: instance.part for instance in space.instances}
    G_structures = similarity_matrix(structures, part_of)
    similarity_seconds = time.perf_counter() - started
    D = squareform(pdist(X)) if layout.size else np.zeros((len(X), len(X)))
    G = G_structures[np.ix_(labels, labels)]
    F, info = fuse(D, G, space.fusion_margin, space.fusion_solver)
    info.update(
        {
            "n_structures": len(structures),
            "n_references": len(X),
            "spec_dim": layout.size,
            "similarity_seconds": similarity_seconds,
        }
    )
    return F, labels, info


def structure_distances(F: np.ndarray, labels: np.ndarray, count: int) -> np.ndarray:
    """Energy distances between the structures' reference clouds under the fused
    distances F, floored (see the module docstring) and scaled to a largest of 1."""
    mean = np.zeros((count, count))
    for a in range(count):
        rows = labels == a
        for b in range(a, count):
            mean[a, b] = mean[b, a] = float(F[np.ix_(rows, labels == b)].mean())
    within = np.diag(mean)
    energy = 2.0 * mean - within[:, None] - within[None, :]
    distance = np.sqrt(np.maximum(energy, 0.0))
    np.fill_diagonal(distance, 0.0)
    largest = float(distance.max())
    if largest <= 0.0:  # every structure alike: all equally far apart
        distance = 1.0 - np.eye(count)
    else:
        distance /= largest
    floor = STRUCTURE_DISTANCE_FLOOR * (1.0 - np.eye(count))
    return np.maximum(distance, floor)


def structure_embedding(distance: np.ndarray) -> np.ndarray:
    """Coordinates (S x k) for structures at the given distances, by classical MDS with
    every positive dimension; if dropping the negative part brought two structures
    closer than half the floor, a small identity block keeps them apart."""
    coords, _ = classical_mds(distance, mass=1.0)
    count = len(distance)
    embedded = squareform(pdist(coords))
    closest = float(np.where(np.eye(count, dtype=bool), np.inf, embedded).min())
    if closest < 0.5 * STRUCTURE_DISTANCE_FLOOR:
        coords = np.hstack([coords, STRUCTURE_DISTANCE_FLOOR / np.sqrt(2.0) * np.eye(count)])
    return coords


def mixed_representation(space: DesignSpace) -> Representation:
    """Structure index + normalised specs, decoded by identity; the fusion places the
    structures (``structure_coords``) for the proposer's structure kernel."""
    layout = spec_layout(space)
    structures = layout.structures
    started = time.perf_counter()
    F, labels, info = fused_references(space)
    distance = structure_distances(F, labels, len(structures))
    coords = structure_embedding(distance)
    info.update(
        {
            "dim": 1 + layout.size,
            "structure_dim": int(coords.shape[1]),
            "structure_distance_min": float((distance + np.eye(len(distance))).min()),
            "structure_distance_median": float(
                np.median(distance[np.triu_indices(len(distance), 1)])
            ),
            "build_seconds": time.perf_counter() - started,
        }
    )
    return Representation(
        kind="mixed",
        spec_names=layout.names,
        spec_low=layout.low.tolist(),
        spec_high=layout.high.tolist(),
        structures=structures,
        bounds=mixed_bounds(len(structures), layout.size),
        structure_coords=coords.tolist(),
        info=info,
    )


def build_representation(space: DesignSpace) -> Representation:
    """The study's representation: identity for one structure, else the one its
    ``encoding`` names: ``mixed`` (the default), ``fused`` (the preprint's) or
    ``onehot``."""
    layout = spec_layout(space)
    structures = layout.structures
    if len(structures) == 1:
        return identity_representation(space)
    if space.encoding == "onehot":
        return onehot_representation(space)
    if space.encoding == "mixed":
        return mixed_representation(space)
    started = time.perf_counter()
    F, labels, info = fused_references(space)
    X, _ = reference_specs(space)
    max_dim = space.embedding_max_dim or max(
        1, layout.size + min(len(structures) - 1, MAX_STRUCTURE_DIMS)
    )
    coords, embedding = classical_mds(F, space.embedding_mass, max_dim)
    info.update(embedding)
    affine = []
    squared_error = 0.0
    for index in range(len(structures)):
        rows = labels == index
        design = np.column_stack([coords[rows], np.ones(int(rows.sum()))])
        matrix, *_ = np.linalg.lstsq(design, X[rows], rcond=None)
        affine.append(matrix)
        used = layout.used_slots(structures[index])
        squared_error += float(np.sum((design @ matrix - X[rows])[:, used] ** 2))
    used_count = sum(int(layout.used_slots(structures[s]).sum()) for s in labels)
    info["affine_rms_residual"] = float(np.sqrt(squared_error / max(used_count, 1)))
    low, high = coords.min(axis=0), coords.max(axis=0)
    widen = 0.05 * np.maximum(high - low, 1e-9)
    embedded = squareform(pdist(coords))
    upper = np.triu_indices(len(X), 1)
    info.update(
        {
            "embedding_stress": float(
                np.linalg.norm(embedded[upper] - F[upper])
                / max(float(np.linalg.norm(F[upper])), 1e-300)
            ),
            "build_seconds": time.perf_counter() - started,
        }
    )
    return Representation(
        kind="fused",
        spec_names=layout.names,
        spec_low=layout.low.tolist(),
        spec_high=layout.high.tolist(),
        structures=structures,
        bounds=[(low - widen).tolist(), (high + widen).tolist()],
        ref_coords=coords.tolist(),
        ref_structure=labels.astype(int).tolist(),
        affine=[matrix.tolist() for matrix in affine],
        info=info,
    )


def search_structure(space: DesignSpace, representation: Representation) -> SearchStructure | None:
    """What the proposer needs to model a design vector (``SearchStructure``), for
    the identity and mixed representations; None for the fused and one-hot ones,
    which the proposer treats as plain boxes."""
    if representation.kind not in ("identity", "mixed"):
        return None
    layout = spec_layout(space)
    used = np.array([layout.used_slots(structure) for structure in layout.structures])
    if representation.kind == "mixed":
        coords = np.asarray(representation.structure_coords, dtype=np.float64)
    else:
        coords = np.zeros((1, 1))
    column = {name: k for k, name in enumerate(layout.names)}
    axes = []
    for instance in space.instances:
        theta_key = f"{instance.name}.joint.axis_theta"
        phi_key = f"{instance.name}.joint.axis_phi"
        if theta_key not in column and phi_key not in column:
            continue
        lower = space.joint_spec(instance.name, "lower")
        upper = space.joint_spec(instance.name, "upper")
        symmetric = (
            not isinstance(lower, Bound)
            and not isinstance(upper, Bound)
            and math.isclose(lower, -upper)
        )
        axes.append(
            AxisColumns(
                theta=column.get(theta_key, -1),
                phi=column.get(phi_key, -1),
                theta_fixed=layout.fixed.get(theta_key, 0.0),
                phi_fixed=layout.fixed.get(phi_key, 0.0),
                sign_invariant=symmetric,
            )
        )
    return SearchStructure(
        structure_coords=coords,
        used=used,
        spec_low=layout.low,
        spec_high=layout.high,
        axes=tuple(axes),
        pad=PAD,
        spec_log=layout.log if layout.log.any() else None,
        choices=choice_columns(layout),
    )


def choice_columns(layout: SpecLayout) -> tuple[ChoiceColumns, ...]:
    """Each choosing part's or joint's searched entries (its own slots, not a tied
    instance's) and where each component lies in them."""
    column = {name: k for k, name in enumerate(layout.names)}
    found = []
    for owner in layout.chooses:
        keys = [key for key in layout.names if key.startswith(f"{owner}.choice.")]
        if not keys:
            continue
        columns = [column[key] for key in keys]
        entries = [key.removeprefix(f"{owner}.choice.") for key in keys]
        catalogue = layout.catalogue_of(owner)
        rows = []
        for component in catalogue:
            row = layout.denormalise(np.full(layout.size, 0.5))
            row[columns] = [coordinate(catalogue, component, entry) for entry in entries]
            rows.append(layout.normalise(row)[columns])
        found.append(ChoiceColumns(columns=tuple(columns), points=np.array(rows)))
    return tuple(found)
