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

from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ProposalRequest:
    """A study's history, as arrays.

    X, y: completed trials in trial-number order; y oriented to be maximised.
    failed: vectors of failed trials. pending: vectors of queued or running trials.
    bounds: (2, d) search box. n_issued: how many trials the study has created so
    far (a position in a space-filling sequence). seed: the study's seed.
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

    @property
    def dim(self) -> int:
        return int(self.bounds.shape[1])


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

    def propose(self, request: ProposalRequest) -> Proposal: ...


def empty_history(dim: int) -> FloatArray:
    return np.zeros((0, dim), dtype=np.float64)
