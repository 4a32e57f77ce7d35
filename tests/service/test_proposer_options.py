"""Each proposer declares its options; the same model checks a new study's options and
is what the proposer reads them with, and checking them stays light."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from pydantic import ValidationError

from adservice.proposers import available, get_proposer, options_model
from adservice.proposers.base import ProposalRequest, empty_history

BOUNDS = np.array([[0.0, -1.0], [1.0, 1.0]])


def request(options: dict[str, object], *, n: int = 6, count: int = 2) -> ProposalRequest:
    rng = np.random.default_rng(3)
    X = BOUNDS[0] + rng.random((n, 2)) * (BOUNDS[1] - BOUNDS[0])
    y = -np.sum((X - [0.3, 0.2]) ** 2, axis=1)
    return ProposalRequest(
        bounds=BOUNDS,
        count=count,
        seed=1,
        n_issued=n,
        X=X,
        y=y,
        failed=empty_history(2),
        pending=empty_history(2),
        n_initial=2,
        options=options,
    )


def test_checking_options_imports_no_model_library() -> None:
    code = (
        "import sys\n"
        "from adservice.proposers import available, options_model\n"
        "for name in available():\n"
        "    options_model(name).model_validate({})\n"
        "options_model('qei').model_validate({'kernel': 'matern', 'num_restarts': 3})\n"
        "heavy = [m for m in ('torch', 'botorch', 'gpytorch', 'optuna') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("name", available())
def test_a_proposer_reads_its_options_with_its_declared_model(name: str) -> None:
    proposer = get_proposer(name)
    assert proposer.options_model is options_model(name)
    with pytest.raises(ValidationError, match="not_an_option"):
        proposer.propose(request({"not_an_option": 1}))
    assert proposer.propose(request({})).candidates.shape == (2, 2)


def test_qei_with_only_raw_samples_starts_no_more_restarts_than_samples() -> None:
    """Regression: raw_samples below the default restarts made every model ask fall
    back to Sobol points."""
    proposal = get_proposer("qei").propose(request({"raw_samples": 3}, count=1))
    (info,) = proposal.info
    assert info["method"] == "LogEI", info
    assert (info["num_restarts"], info["raw_samples"]) == (3, 3)
