"""The proposer interface: arrays in, candidate vectors out.

A proposer knows nothing of the database or HTTP. The service gathers a study's
history into a :class:`ProposalRequest` (always oriented so that *larger is
better*), calls :meth:`Proposer.propose` in a worker thread, and stores the
candidates as new trials. Proposers are stateless between calls: anything they
need (a Nelder-Mead simplex, a TPE history) is rebuilt from the request, so a
restarted or second server proposes exactly the same thing.

Each proposer declares the ``options`` it takes as a :class:`ProposerOptions` model,
which the service checks when a study is created (unknown keys, wrong types and
unknown choices are refused there) and the proposer parses its options with. The
model lives in the proposer's module, which must stay cheap to import: torch,
BoTorch and Optuna are imported inside ``propose``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict

if TYPE_CHECKING:
    from adclient.boxspace import BoxEncoding
    from adclient.polytope import SpecPolytope

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class AxisColumns:
    """A joint axis searched as two angles (``adclient.design``'s convention).

    ``theta``/``phi``: the spec-vector columns holding the normalised angles, or -1
    when that angle is fixed (``theta_fixed``/``phi_fixed`` radians). The model sees
    the unit axis instead of the angles, which have a pole and a wrap-around;
    ``sign_invariant`` axes (a joint whose limits are symmetric, so axis -u with angle
    -q is the same joint as u with q) are seen as the line through u.
    """

    theta: int
    phi: int
    theta_fixed: float = 0.0
    phi_fixed: float = 0.0
    sign_invariant: bool = False


@dataclass(frozen=True)
class ChoiceColumns:
    """A part's or joint's choice from a catalogue (``adclient.catalogues``): the
    spec-vector ``columns`` of its searched entries, and ``points`` (components x
    columns), each component's normalised entries, where a vector that picks it is
    put (``StudyConfig.canonical``)."""

    columns: tuple[int, ...]
    points: FloatArray


@dataclass(frozen=True)
class SearchStructure:
    """What a design vector means, for proposers that model it (qei).

    With several structures a vector is ``[structure index, spec vector]`` (the
    ``mixed`` representation: the index is searched in [-0.5, S - 0.5] and rounded),
    with one it is the spec vector alone. Spec values are normalised to [0, 1];
    ``used[s]`` marks the slots structure s uses, the others are ``pad`` whatever a
    vector holds there. ``structure_coords`` (S x k) place the structures in the
    fused geometry; ``spec_low``/``spec_high`` are the slots' physical ranges and
    ``spec_log`` marks the slots normalised on a log scale (None: none is); ``scale``
    says how to turn a normalised slot back into its value (the model needs a joint
    axis's angles). The model itself sees the normalised slots: a log spec on its log
    scale, as the proposers search it.
    """

    structure_coords: FloatArray
    used: NDArray[np.bool_]
    spec_low: FloatArray
    spec_high: FloatArray
    axes: tuple[AxisColumns, ...] = ()
    pad: float = 0.5
    spec_log: NDArray[np.bool_] | None = None
    choices: tuple[ChoiceColumns, ...] = ()

    def is_log(self, column: int) -> bool:
        return self.spec_log is not None and bool(self.spec_log[column])

    def scale(self, column: int) -> tuple[float, float]:
        """(start, width) of a slot on its own scale: value = start + u * width, then
        exp of that for a log slot."""
        low, high = float(self.spec_low[column]), float(self.spec_high[column])
        if self.is_log(column):
            low, high = math.log(low), math.log(high)
        return low, high - low

    @property
    def n_structures(self) -> int:
        return int(self.structure_coords.shape[0])

    @property
    def spec_dim(self) -> int:
        return int(self.used.shape[1])


def model_inputs(X: np.ndarray, bounds: np.ndarray, search: SearchStructure | None) -> np.ndarray:
    """Search vectors (n x d) -> model inputs ``[structure index, u]``: ``u`` the spec
    vector (already in [0, 1]) or the box coordinates scaled to the unit box, the
    index 0 for a single structure; unused slots at the pad value."""
    X = np.asarray(X, dtype=np.float64).reshape(-1, bounds.shape[1])
    if search is None:
        unit = (X - bounds[0]) / (bounds[1] - bounds[0])
        return np.column_stack([np.zeros(len(X)), unit])
    if search.n_structures > 1:
        index = _tree_index(X[:, 0], search)
        specs = np.clip(X[:, 1:], 0.0, 1.0)
    else:
        index = np.zeros(len(X))
        specs = np.clip(X, 0.0, 1.0)
    used = search.used[index.astype(np.int64)]
    return np.column_stack([index, np.where(used, specs, search.pad)])


def search_vectors(Z: np.ndarray, bounds: np.ndarray, search: SearchStructure | None) -> np.ndarray:
    """Model inputs -> search vectors (the inverse of ``model_inputs`` on canonical points)."""
    if search is None:
        return bounds[0] + Z[:, 1:] * (bounds[1] - bounds[0])
    if search.n_structures > 1:
        return Z.copy()
    return Z[:, 1:].copy()


@dataclass(frozen=True)
class SpecRegion:
    """A design space's spec constraints over model inputs (``acquisition.maximise``
    keeps its search inside): which points satisfy them, and the nearest that do."""

    polytope: SpecPolytope
    bounds: np.ndarray
    search: SearchStructure | None

    def holds(self, Z: np.ndarray) -> np.ndarray:
        return self.polytope.holds(search_vectors(Z, self.bounds, self.search))

    def inside(self, Z: np.ndarray) -> np.ndarray:
        from adservice.feasibility import into_polytope

        vectors, moved = into_polytope(
            search_vectors(Z, self.bounds, self.search), self.polytope, self.bounds
        )
        return model_inputs(vectors, self.bounds, self.search) if moved.any() else Z


@dataclass(frozen=True)
class FidelityHistory:
    """What the multi-fidelity proposer (``adservice.proposers.fidelity``) knows of a
    study's fidelity: ``grid`` (the fidelities a trial may
    train to, lowest first, the last the target) and each one's ``cost``; ``observed`` and
    ``pending`` the fidelity of each row of ``X`` and of ``pending``; ``remaining`` the
    trials the study may still create (None: no limit)."""

    grid: FloatArray
    cost: FloatArray
    observed: FloatArray
    pending: FloatArray
    remaining: int | None = None

    def level(self, steps: FloatArray) -> FloatArray:
        """Fidelities on the model's scale: 0 at the lowest, 1 at the target, log-spaced."""
        low, high = math.log(self.grid[0]), math.log(self.grid[-1])
        clipped = np.clip(np.asarray(steps, dtype=np.float64), self.grid[0], self.grid[-1])
        return (np.log(clipped) - low) / (high - low)


@dataclass(frozen=True)
class ProposalRequest:
    """A study's history, as arrays.

    X, y: completed trials in trial-number order; y oriented to be maximised.
    failed: vectors of failed trials. pending: vectors of queued or running trials.
    bounds: (2, d) search box. n_issued: how many trials the study has created so
    far (a position in a space-filling sequence). seed: the study's seed.
    structure: what the coordinates of a design vector mean (None: a plain box).
    box: for a box of typed params (int, log, step, categorical), how its vectors
    encode them (``adclient.boxspace``): proposers search ``bounds``, the service snaps
    what they return; X, failed and pending hold snapped vectors. None: every
    coordinate is a plain float.
    seconds, memory_bytes: the server's budget for this ask (None: no limit); a
    proposer that models stops at the time budget and keeps within the memory one,
    recording in the info what it gave up (see ``qei``).

    Several objectives and outcome constraints (only for a proposer whose
    ``multi_objective`` / ``constrained`` is true, the service refuses a study whose
    proposer lacks what it needs):
    objectives: (n, m) the objective values of X's trials, m >= 2, each column
    oriented to be maximised; None for one objective (then ``y`` as always). When
    set, ``y == objectives[:, 0]``, so a proposer that reads only ``y`` still runs.
    ref_point: (m,) the hypervolume reference point, oriented like ``objectives``;
    None: the proposer infers it.
    slacks: (n, c) constraint slacks of X's trials, a trial satisfying constraint j
    when ``slacks[:, j] <= 0`` (BoTorch's convention); None: no constraints. Also
    with one objective.

    spec_polytope: a design space's spec constraints, ``A v <= b`` over search vectors
    (``adclient.polytope``); None: none. The service moves a candidate that breaks one
    to the nearest that does not, so a proposer may ignore them; one that reads them
    (random draws again, qei scores only feasible points) proposes better.
    """

    bounds: FloatArray
    count: int
    seed: int
    n_issued: int
    X: FloatArray
    y: FloatArray
    failed: FloatArray
    pending: FloatArray
    n_initial: int = 2
    noisy: bool = False
    options: dict[str, Any] = field(default_factory=dict)
    structure: SearchStructure | None = None
    box: BoxEncoding | None = None
    seconds: float | None = None
    memory_bytes: int | None = None
    objectives: FloatArray | None = None
    ref_point: FloatArray | None = None
    slacks: FloatArray | None = None
    spec_polytope: SpecPolytope | None = None
    fidelities: FidelityHistory | None = None
    """A study with ``task.fidelity``: each trial's fidelity and the grid and costs the
    multi-fidelity proposer (``adservice.proposers.fidelity``) chooses among; None: none."""

    @property
    def dim(self) -> int:
        return int(self.bounds.shape[1])


DEGRADED = "degraded"
"""Info key (true) of a candidate that is not what the proposer would have chosen, for a
reason the study's owner should see (a time or memory budget, a model that failed): the
service counts them on the study (``proposal_fallbacks``, /metrics, dashboard, status)."""


@dataclass(frozen=True)
class Proposal:
    """``candidates``: (count, d) inside the bounds. ``info``: one JSON-able dict
    per candidate, stored on its trial (how it was chosen, fallbacks taken)."""

    candidates: FloatArray
    info: list[dict[str, Any]]


class ProposerOptions(BaseModel):
    """Base of every proposer's options: no unknown keys, no NaN or infinity."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)


class NoOptions(ProposerOptions):
    """For proposers that take no options: any key is an error."""


class Proposer(Protocol):
    name: ClassVar[str]
    needs_history: ClassVar[bool]
    """False when the proposer uses only bounds, count, seed and n_issued, so the
    service can skip loading the history (the hot path of cheap proposers)."""
    options_model: ClassVar[type[ProposerOptions]]
    """What ``ProposalRequest.options`` may hold."""
    multi_objective: ClassVar[bool]
    """True when the proposer reads ``ProposalRequest.objectives`` (several
    objectives); the service refuses a multi-objective study of any other."""
    constrained: ClassVar[bool]
    """True when the proposer reads ``ProposalRequest.slacks`` (outcome constraints);
    the service refuses a constrained study of any other."""

    def propose(self, request: ProposalRequest) -> Proposal: ...


MAX_FAILED_AS_PENDING = 32
"""The latest failed trials an ask keeps away from as pending points (the model leaves
every failed trial out)."""


def design_trees(X: np.ndarray, search: SearchStructure) -> np.ndarray:
    """The structure index of each search vector (row of ``X``) whose index is finite,
    as ``model_inputs`` reads it."""
    X = np.asarray(X, dtype=np.float64)
    index = X[:, 0] if X.ndim == 2 and len(X) else np.zeros(0)
    return _tree_index(index[np.isfinite(index)], search).astype(np.int64)


def _tree_index(column: np.ndarray, search: SearchStructure) -> np.ndarray:
    """A search vector's structure column as the structure it names (the nearest)."""
    return np.clip(np.floor(column + 0.5), 0, search.n_structures - 1)


def empty_history(dim: int) -> FloatArray:
    return np.zeros((0, dim), dtype=np.float64)
