"""Proposer registry: a study names its proposer; the service looks it up here.

Model-based proposers are imported on first use, so importing the registry (to list
or validate names) does not pull in torch or Optuna.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

from adservice.proposers.base import Proposal, ProposalRequest, Proposer
from adservice.proposers.simple import RandomProposer, SobolProposer


def _lazy(module: str, attribute: str) -> Callable[[], Proposer]:
    def factory() -> Proposer:
        proposer_class = getattr(importlib.import_module(module), attribute)
        return proposer_class()

    return factory


_FACTORIES: dict[str, Callable[[], Proposer]] = {
    RandomProposer.name: RandomProposer,
    SobolProposer.name: SobolProposer,
    "qei": _lazy("adservice.proposers.qei", "QLogEIProposer"),
    "nelder-mead": _lazy("adservice.proposers.neldermead", "NelderMeadProposer"),
    "tpe": _lazy("adservice.proposers.tpe", "TPEProposer"),
}

DEFAULT_PROPOSER = "qei"


def available() -> list[str]:
    return sorted(_FACTORIES)


def get_proposer(name: str) -> Proposer:
    """The proposer named ``name``; KeyError for an unknown name."""
    return _FACTORIES[name]()


__all__ = [
    "DEFAULT_PROPOSER",
    "Proposal",
    "ProposalRequest",
    "Proposer",
    "available",
    "get_proposer",
]
