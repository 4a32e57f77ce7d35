"""The greedy batch search of ``qei``'s model phases (one objective in ``qei``, several
objectives or constraints in ``multiobjective``): each step maximises its acquisition
over the mixed domain (``acquisition.maximise``) with the previous steps' candidates
pending. With ``second_looks: thompson`` (the default) a step that is a look turn
(``initial.thompson_turn``) whose posterior draw favours another tree than the
incumbent's (``looks.drawn_tree``) is a random design of that tree, and one whose draw
favours the incumbent's tree, with ``floor_looks``, a random design of a tree whose one
design scored on the start's floor (``initial.floor_trees``); with ``judged`` or
``always`` a step that is a second look (``initial.second_look``) maximises the
acquisition over the structures observed once: with ``judged`` over those the tree
judgement (``looks.tree_chances``) gives a chance of beating the incumbent, with
``always`` over all of them. Imported only when a proposal is computed."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from adservice.proposers.base import (
    MAX_FAILED_AS_PENDING,
    ProposalRequest,
    SpecRegion,
    design_trees,
    model_inputs,
    search_vectors,
)
from adservice.proposers.initial import (
    LOOK_CHANCE,
    LOOK_DESIGNS,
    floor_trees,
    initial_count,
    second_look,
    thompson_turn,
)
from adservice.proposers.simple import REJECTION_DRAWS, derived_seed

if TYPE_CHECKING:
    import torch

    from adservice.proposers.qei_shared import QEIOptions
    from adservice.proposers.trust_region import TrustBox

DEFAULT_RESTARTS = 10
"""Local searches per candidate (GPSampler's n_local_search)."""
DEFAULT_RAW_SAMPLES = 2048
"""Sobol points the starts are chosen from (GPSampler's n_preliminary_samples)."""
LOOK_BATCH = 64
"""Random designs a Thompson look draws at a time to find one inside the spec constraints."""


@dataclass(frozen=True)
class Step:
    """One greedy step's acquisition, its name, and optionally a cheaper estimate of it
    that scores the raw samples (``acquisition.maximise``'s ``screen``)."""

    acqf: Any
    method: str
    screen: Any = None


@dataclass(frozen=True)
class Found:
    """A greedy batch's candidates (model inputs) and what each step recorded."""

    chosen: list[np.ndarray]
    methods: list[str]
    values: list[float]
    switched: int
    second_looks: list[bool]
    chances: list[dict[str, float] | None]
    """Per step, the judged trees' chances (``looks.tree_chances``), None if none judged."""


@dataclass(frozen=True)
class Greedy:
    """One ask's greedy batch search: its sizes, domain, starts and the points it must
    not propose again."""

    domain: Any
    raw_count: int
    num_restarts: int
    maxiter: int
    incumbents: np.ndarray
    pending_Z: np.ndarray
    taken: np.ndarray | None
    tkw: dict[str, Any]
    deadline: float | None
    n_incumbents: int = 1
    region: SpecRegion | None = None
    structure_counts: np.ndarray | None = None
    """Observed and pending designs per structure (None: one structure)."""
    end_number: int = 0
    """The study's number of the candidate after this ask's last."""
    n_start: int = 0
    """The study's initial designs (``initial.initial_count``)."""
    trust: TrustBox | None = None
    """A long history's trust region: the search stays inside it (``trust_region``)."""
    judged: bool = False
    """A look chooses among the trees the judgement passes (``second_looks: judged``)."""
    thompson: bool = False
    """Looks are Thompson looks (``second_looks: thompson``)."""
    floor: np.ndarray | None = None
    """Per structure, whether its designs all scored on the start's floor
    (``initial.floor_trees``; ``floor_looks``); None: no floor looks."""

    @classmethod
    def of(
        cls,
        request: ProposalRequest,
        options: QEIOptions,
        bounds: np.ndarray,
        Z: np.ndarray,
        X_pending: np.ndarray,
        incumbents: np.ndarray,
        tkw: dict[str, Any],
        deadline: float | None,
        default_raw: int = DEFAULT_RAW_SAMPLES,
        n_incumbents: int = 1,
    ) -> Greedy:
        """The search of this ask: its sizes from ``options`` (``default_raw`` raw
        samples unless they say), the observed points ``Z`` and ``X_pending`` taken
        (noise-free studies), ``incumbents`` (model inputs, best first) to start from."""
        from adservice.proposers.acquisition import DiscreteColumns, MixedDomain

        search = request.structure
        if options.num_restarts is not None:
            num_restarts = options.num_restarts
        else:
            num_restarts = min(DEFAULT_RESTARTS, options.raw_samples or DEFAULT_RESTARTS)
        spec_dim = Z.shape[1] - 1
        domain = MixedDomain(
            used=search.used if search is not None else np.ones((1, spec_dim), dtype=bool),
            pad=search.pad if search is not None else 0.5,
            discrete=DiscreteColumns(request.box, bounds[0], bounds[1] - bounds[0])
            if request.box is not None
            else None,
            choices=search.choices if search is not None else (),
            spec_width=search.spec_high - search.spec_low if search is not None else None,
        )
        pending_Z = model_inputs(X_pending, bounds, search) if len(X_pending) else Z[:0]
        counts = floor = None
        if options.second_looks != "off" and search is not None and search.n_structures > 1:
            # every trial the study has, not only those the model trains on: observed
            # (whatever their values), failed (the older ones are not pending points),
            # pending and this ask's start designs (the last two are in X_pending)
            failed = np.asarray(request.failed, dtype=np.float64)
            older = failed[: max(0, len(failed) - MAX_FAILED_AS_PENDING)]
            trees = [design_trees(part, search) for part in (request.X, older, X_pending)]
            counts = np.bincount(np.concatenate(trees), minlength=search.n_structures)
            if options.second_looks == "thompson" and options.floor_looks:
                y = np.asarray(request.y, dtype=np.float64).reshape(-1)
                X = np.asarray(request.X, dtype=np.float64).reshape(len(y), -1)
                usable = np.isfinite(y) & np.all(np.isfinite(X), axis=1)
                floor = floor_trees(
                    design_trees(X[usable], search),
                    y[usable],
                    initial_count(request),
                    search.n_structures,
                )
        return cls(
            domain=domain,
            raw_count=options.raw_samples or max(default_raw, num_restarts),
            num_restarts=num_restarts,
            maxiter=options.maxiter,
            incumbents=incumbents,
            pending_Z=pending_Z,
            taken=None if request.noisy else np.concatenate([Z, pending_Z]),
            tkw=tkw,
            deadline=deadline,
            n_incumbents=n_incumbents,
            region=SpecRegion(request.spec_polytope, bounds, search)
            if request.spec_polytope is not None
            else None,
            structure_counts=counts,
            floor=floor,
            end_number=request.n_issued + request.count,
            n_start=initial_count(request),
            judged=options.second_looks == "judged",
            thompson=options.second_looks == "thompson",
        )

    def run(
        self,
        q: int,
        seed: int,
        acquisition_at: Callable[[int, torch.Tensor | None], Step],
        judge: Callable[[np.ndarray, int], np.ndarray] | None = None,
        draw: Callable[[np.ndarray, int], int] | None = None,
    ) -> Found:
        """Up to q candidates (fewer past the deadline); ``acquisition_at(step_seed,
        pending)`` gives each step's acquisition; ``judge(trees, step_seed)`` each
        tree's chance of beating the incumbent (``looks.tree_chances``; without it a
        judged look is a free choice); ``draw(trees, step_seed)`` the tree a posterior
        draw favours (``looks.drawn_tree``; without it a Thompson look turn is a free
        choice)."""
        import torch

        from adservice.proposers.acquisition import TAKEN_TOL, maximise, past

        found = Found(chosen=[], methods=[], values=[], switched=0, second_looks=[], chances=[])
        switched = 0
        for step in range(q):
            if step and past(self.deadline):
                break
            step_seed = derived_seed(seed, step)
            new = [z[None, :] for z in found.chosen]
            taken = None if self.taken is None else np.concatenate([self.taken, *new])
            structures = None
            if self.structure_counts is not None:
                counts = self.structure_counts.copy()
                for z in found.chosen:
                    counts[round(float(z[0]))] += 1
                number = self.end_number - q + step
                if self.thompson:
                    method = "thompson"
                    look = self._thompson_look(counts, number, step_seed, draw, taken)
                    if look is None and draw is not None:
                        method = "floor-look"
                        look = self._floor_look(counts, number, step_seed, taken)
                    if look is not None:
                        found.chosen.append(look)
                        found.methods.append(method)
                        found.values.append(float("nan"))
                        found.second_looks.append(True)
                        found.chances.append(None)
                        continue
                else:
                    structures = second_look(counts, number, self.n_start)
            batch_pending = np.concatenate([self.pending_Z, *new])
            pending_t = torch.as_tensor(batch_pending, **self.tkw) if len(batch_pending) else None
            current = acquisition_at(step_seed, pending_t)
            chances = None
            if structures is not None and self.judged:
                if judge is None:
                    structures = None
                else:
                    odds = judge(structures, step_seed)
                    chances = {
                        str(t): round(float(c), 3) for t, c in zip(structures, odds, strict=True)
                    }
                    structures = structures[odds >= LOOK_CHANCE]
                    structures = structures if len(structures) else None
            acqf, screen, incumbents = current.acqf, current.screen, self.incumbents
            taken_tol: float | np.ndarray = TAKEN_TOL
            if self.trust is not None:
                acqf, screen = self.trust.wrap(acqf, self.tkw), self.trust.wrap(screen, self.tkw)
                incumbents = self.trust.to_unit(incumbents)
                taken = None if taken is None else self.trust.to_unit(taken, clip=False)
                # qei's duplicate bound in the model's inputs, in the box's units
                taken_tol = np.concatenate([[TAKEN_TOL], TAKEN_TOL / self.trust.width])
            optimum = maximise(
                acqf,
                self.domain,
                raw_count=self.raw_count,
                num_restarts=self.num_restarts,
                maxiter=self.maxiter,
                seed=step_seed,
                incumbents=incumbents,
                tkw=self.tkw,
                deadline=self.deadline,
                taken=taken,
                taken_tol=taken_tol,
                screen=screen,
                n_incumbents=self.n_incumbents,
                region=self.region,
                structures=structures,
            )
            found.chosen.append(
                optimum.z if self.trust is None else self.trust.from_unit(optimum.z)
            )
            found.methods.append(current.method)
            found.values.append(optimum.value)
            found.second_looks.append(structures is not None)
            found.chances.append(chances)
            switched += optimum.structures_switched
        return Found(
            found.chosen, found.methods, found.values, switched, found.second_looks, found.chances
        )

    def _thompson_look(
        self,
        counts: np.ndarray,
        number: int,
        step_seed: int,
        draw: Callable[[np.ndarray, int], int] | None,
        taken: np.ndarray | None,
    ) -> np.ndarray | None:
        """A Thompson look's design (model inputs): a random design of the tree a
        posterior draw favours; None for a free choice (not a look turn, the draw
        favours the incumbent's tree or one with more than ``LOOK_DESIGNS`` designs, or
        the random design was proposed before)."""
        if draw is None or not thompson_turn(counts, number, self.n_start):
            return None
        tree = draw(np.arange(len(counts)), step_seed)
        if tree == round(float(self.incumbents[0, 0])) or counts[tree] > LOOK_DESIGNS:
            return None
        return self._random_design(tree, step_seed, taken)

    def _floor_look(
        self, counts: np.ndarray, number: int, step_seed: int, taken: np.ndarray | None
    ) -> np.ndarray | None:
        """A floor look's design (model inputs): on a look turn the draw left to the
        model, a random design of a tree, drawn at random, whose one design scored on the
        start's floor (``floor``); None where there is none (or without floor looks)."""
        if self.floor is None or not thompson_turn(counts, number, self.n_start):
            return None
        trees = np.flatnonzero(self.floor & (counts == 1))
        trees = trees[trees != round(float(self.incumbents[0, 0]))]
        if not len(trees):
            return None
        tree = int(trees[np.random.default_rng([step_seed, 40]).integers(len(trees))])
        return self._random_design(tree, step_seed, taken)

    def _random_design(
        self, tree: int, step_seed: int, taken: np.ndarray | None
    ) -> np.ndarray | None:
        """A random design of ``tree`` (model inputs), inside the spec constraints; None
        where it was proposed before."""
        from adservice.proposers.acquisition import TAKEN_TOL, nearest_distance, raw_samples

        rng = np.random.default_rng([step_seed, 39])
        look = raw_samples(self.domain, 1, rng, np.array([tree]))
        if self.region is not None:
            # uniform over the tree's designs that satisfy the spec constraints: draw until
            # one does (as the random proposer), and move the first inside only past that
            for _ in range(REJECTION_DRAWS // LOOK_BATCH):
                if self.region.holds(look)[0]:
                    break
                drawn = raw_samples(self.domain, LOOK_BATCH, rng, np.array([tree]))
                inside = np.flatnonzero(self.region.holds(drawn))
                look = drawn[inside[:1]] if len(inside) else look
            look = self.region.inside(look)
        if taken is not None and nearest_distance(taken, look[0]) < TAKEN_TOL:
            return None
        return look[0]

    def rows(
        self,
        found: Found,
        request: ProposalRequest,
        bounds: np.ndarray,
        model: Any,
        extra: dict[str, Any],
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """The candidates as search vectors, and ``extra`` with what every model phase
        records (``model``: the GP whose structure kernel is reported)."""
        from adservice.proposers.acquisition import past
        from adservice.proposers.gpmodel import structure_correlation, structure_lengthscale

        search = request.structure
        rows_np = search_vectors(np.array(found.chosen), bounds, search)
        if not np.all(np.isfinite(rows_np)):
            raise FloatingPointError("non-finite candidates from the acquisition optimiser")
        value = found.values[0]
        extra.update(
            methods=found.methods,
            log_acq_value=value if np.isfinite(value) else None,
            num_restarts=self.num_restarts,
            raw_samples=self.raw_count,
            device=self.tkw["device"].type,
        )
        if past(self.deadline):
            extra.update(budget="time", budget_seconds=request.seconds)
        if search is not None and search.n_structures > 1:
            extra["structure_lengthscale"] = structure_lengthscale(model)
            extra["structure_correlation"] = structure_correlation(model, search, self.tkw)
            extra["structures_switched"] = found.switched
            extra["second_looks"] = found.second_looks
            extra["tree_chances"] = found.chances
        return rows_np, extra
