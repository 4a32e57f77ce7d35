"""Proposer registry: a study names its proposer; the service looks it up here."""

from __future__ import annotations

from collections.abc import Callable

from adservice.proposers.base import Proposal, ProposalRequest, Proposer
from adservice.proposers.simple import RandomProposer, SobolProposer

_FACTORIES: dict[str, Callable[[], Proposer]] = {
    RandomProposer.name: RandomProposer,
    SobolProposer.name: SobolProposer,
}


def available() -> list[str]:
    return sorted(_FACTORIES)


def get_proposer(name: str) -> Proposer:
    """The proposer named ``name``; KeyError for an unknown name."""
    return _FACTORIES[name]()


__all__ = ["Proposal", "ProposalRequest", "Proposer", "available", "get_proposer"]
