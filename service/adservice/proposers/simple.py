"""Proposers that need no model: uniform random and scrambled Sobol."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from scipy.stats import qmc

from adservice.proposers.base import NoOptions, Proposal, ProposalRequest, ProposerOptions


def scale_to_bounds(unit: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    return bounds[0] + unit * (bounds[1] - bounds[0])


REJECTION_DRAWS = 1000
"""Draws a random proposal makes at most to land inside a design space's spec
constraints; past them the service moves the last draw inside."""


class RandomProposer:
    """Uniform samples; trial ``n`` always draws from the stream seeded by (seed, n).
    Within spec constraints, uniform over the designs that satisfy them: the stream
    draws until one does (rejection sampling)."""

    name: ClassVar[str] = "random"
    needs_history: ClassVar[bool] = False
    multi_objective: ClassVar[bool] = True  # ignores the history
    constrained: ClassVar[bool] = True
    options_model: ClassVar[type[ProposerOptions]] = NoOptions

    def propose(self, request: ProposalRequest) -> Proposal:
        NoOptions.model_validate(request.options)
        rows, infos = [], []
        for i in range(request.count):
            stream = np.random.default_rng([request.seed, request.n_issued + i])
            row = scale_to_bounds(stream.random(request.dim), request.bounds)
            info: dict[str, object] = {"proposer": self.name}
            if request.spec_polytope is not None:
                draws = 1
                while not request.spec_polytope.holds(row)[0] and draws < REJECTION_DRAWS:
                    row = scale_to_bounds(stream.random(request.dim), request.bounds)
                    draws += 1
                info["draws"] = draws
            rows.append(row)
            infos.append(info)
        return Proposal(candidates=np.array(rows), info=infos)


def derived_seed(*parts: int) -> int:
    """A 31-bit seed that depends on every part (seed 1, n 0 and seed 0, n 1 differ)."""
    words = [int(part) & 0xFFFFFFFF for part in parts]
    return int(np.random.SeedSequence(words).generate_state(1)[0]) & (2**31 - 1)


def sobol_points(dim: int, seed: int, start: int, count: int) -> np.ndarray:
    """Points ``start .. start+count-1`` of the study's scrambled Sobol sequence, in [0,1]^d."""
    engine = qmc.Sobol(d=dim, scramble=True, seed=seed)
    if start:
        engine.fast_forward(start)
    return engine.random(count)


class SobolProposer:
    """The study's scrambled Sobol sequence, continued where the last ask stopped."""

    name: ClassVar[str] = "sobol"
    needs_history: ClassVar[bool] = False
    multi_objective: ClassVar[bool] = True  # ignores the history
    constrained: ClassVar[bool] = True
    options_model: ClassVar[type[ProposerOptions]] = NoOptions

    def propose(self, request: ProposalRequest) -> Proposal:
        NoOptions.model_validate(request.options)
        unit = sobol_points(request.dim, request.seed, request.n_issued, request.count)
        return Proposal(
            candidates=scale_to_bounds(unit, request.bounds),
            info=[
                {"proposer": self.name, "sobol_index": request.n_issued + i}
                for i in range(request.count)
            ],
        )
