"""Proposers that need no model: uniform random and scrambled Sobol."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from scipy.stats import qmc

from adservice.proposers.base import NoOptions, Proposal, ProposalRequest, ProposerOptions


def scale_to_bounds(unit: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    return bounds[0] + unit * (bounds[1] - bounds[0])


class RandomProposer:
    """Uniform samples; trial ``n`` always draws from the stream seeded by (seed, n)."""

    name: ClassVar[str] = "random"
    needs_history: ClassVar[bool] = False
    multi_objective: ClassVar[bool] = True  # ignores the history
    constrained: ClassVar[bool] = True
    options_model: ClassVar[type[ProposerOptions]] = NoOptions

    def propose(self, request: ProposalRequest) -> Proposal:
        NoOptions.model_validate(request.options)
        rows = [
            np.random.default_rng([request.seed, request.n_issued + i]).random(request.dim)
            for i in range(request.count)
        ]
        return Proposal(
            candidates=scale_to_bounds(np.array(rows), request.bounds),
            info=[{"proposer": self.name}] * request.count,
        )


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
