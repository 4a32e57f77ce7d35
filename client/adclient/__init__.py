"""activedesign SDK: API schemas, design spaces, decoding, URDF, HTTP client and CLI."""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"

# The HTTP client is imported on first use, so that importing the schemas alone stays cheap.
_LAZY = {
    "Client": "adclient.client",
    "StudyHandle": "adclient.client",
    "LiveTrial": "adclient.study",
    "TrialPruned": "adclient.pruning",
    "ActiveDesignError": "adclient.errors",
    "ApiError": "adclient.errors",
    "Invalid": "adclient.errors",
    "Unauthorized": "adclient.errors",
    "Forbidden": "adclient.errors",
    "NotFound": "adclient.errors",
    "Conflict": "adclient.errors",
    "PayloadTooLarge": "adclient.errors",
    "Unavailable": "adclient.errors",
    "UnreadableJob": "adclient.errors",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'adclient' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(module), name)
