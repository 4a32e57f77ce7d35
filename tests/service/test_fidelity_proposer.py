"""The multi-fidelity proposer's rule (issue 61), as properties that hold on any machine:
the cheapest budget the model is unsure of, the target at a study's end, and a design
whose short runs the model knows well trained longer."""

from __future__ import annotations

import numpy as np
import pytest

from adclient.schemas.config import Fidelity
from adservice.proposers.base import FidelityHistory, ProposalRequest
from adservice.proposers.fidelity import (
    FidelityProposer,
    choose_level,
    final,
    threshold,
)

FIDELITY = Fidelity(min=512, max=4096, levels=4)


def history(observed: list[float], remaining: int | None = None) -> FidelityHistory:
    grid = np.asarray(FIDELITY.grid(), dtype=np.float64)
    return FidelityHistory(
        grid=grid,
        cost=np.asarray([FIDELITY.cost(steps) for steps in grid]),
        observed=np.asarray(observed, dtype=np.float64),
        pending=np.zeros(0),
        remaining=remaining,
    )


def test_the_cheapest_level_the_model_is_unsure_of_else_the_top() -> None:
    known = history([])
    gamma = threshold(known)
    assert list(known.grid) == [512, 1024, 2048, 4096]
    assert np.all(np.diff(gamma) > 0)  # a dearer level needs more doubt to be chosen
    assert choose_level(gamma + 1.0, known) == 0  # unsure everywhere: the cheapest
    assert choose_level(np.r_[gamma[0] / 2, gamma[1:] + 1.0], known) == 1
    assert choose_level(gamma / 2, known) == 3  # sure of every cheaper level: the top


def test_a_studys_last_fifth_trains_at_the_top() -> None:
    # 20 trials: numbers 16 to 19 are the last fifth; no limit, never
    at_end = [final(history([], remaining=20 - n), n, 0) for n in range(20)]
    assert at_end == [False] * 16 + [True] * 4
    assert final(history([], remaining=5), 15, 1) is True  # the ask's second proposal
    assert final(history([], remaining=None), 10, 0) is False
    assert final(history([], remaining=1), 1, 0) is True  # a study of 2: its last


@pytest.mark.parametrize("seed", range(3))
def test_a_design_whose_short_runs_are_known_is_trained_longer(seed: int) -> None:
    """Short runs that rank designs as the target does, dense over the box, peak at 0.3:
    the next design is near the peak and trained past the shortest budget (its short
    runs leave the model sure of them), whatever the seed."""
    x = np.linspace(0.0, 1.0, 21)
    top = np.array([0.05, 0.95])
    X = np.r_[x, top][:, None]
    y = -((X[:, 0] - 0.3) ** 2)
    steps = [512.0] * len(x) + [4096.0] * len(top)
    request = ProposalRequest(
        bounds=np.array([[0.0], [1.0]]),
        count=1,
        seed=seed,
        n_issued=len(X),
        X=X,
        y=y,
        failed=np.zeros((0, 1)),
        pending=np.zeros((0, 1)),
        n_initial=2,
        fidelities=history(steps, remaining=20),
    )
    proposal = FidelityProposer().propose(request)
    (info,) = proposal.info
    assert info["method"] == "boca"
    assert abs(proposal.candidates[0, 0] - 0.3) < 0.15, info
    assert info["fidelity"] > 512, info
    assert info["fidelity_max"] == 4096
