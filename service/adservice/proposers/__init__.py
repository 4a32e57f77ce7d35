"""Proposer registry: a study names its proposer; the service looks it up here.

Proposer modules are imported on first use, and none imports torch or Optuna at
import time, so listing names or checking a study's options stays light.
"""

from __future__ import annotations

import functools
import importlib

from adservice.proposers.base import Proposal, ProposalRequest, Proposer, ProposerOptions

_CLASSES: dict[str, tuple[str, str]] = {
    "random": ("adservice.proposers.simple", "RandomProposer"),
    "sobol": ("adservice.proposers.simple", "SobolProposer"),
    "qei": ("adservice.proposers.qei", "QLogEIProposer"),
    "nelder-mead": ("adservice.proposers.neldermead", "NelderMeadProposer"),
    "tpe": ("adservice.proposers.tpe", "TPEProposer"),
}

DEFAULT_PROPOSER = "qei"


def available() -> list[str]:
    return sorted(_CLASSES)


@functools.cache
def proposer_class(name: str) -> type[Proposer]:
    """The class of the proposer named ``name``; KeyError for an unknown name. Looked
    up once per name: every ask asks for its study's proposer."""
    module, attribute = _CLASSES[name]
    proposer: type[Proposer] = getattr(importlib.import_module(module), attribute)
    return proposer


def get_proposer(name: str) -> Proposer:
    """The proposer named ``name``; KeyError for an unknown name."""
    return proposer_class(name)()


def options_model(name: str) -> type[ProposerOptions]:
    """What the proposer named ``name`` accepts as ``options``; KeyError if unknown."""
    return proposer_class(name).options_model


__all__ = [
    "DEFAULT_PROPOSER",
    "Proposal",
    "ProposalRequest",
    "Proposer",
    "ProposerOptions",
    "available",
    "get_proposer",
    "options_model",
    "proposer_class",
]
