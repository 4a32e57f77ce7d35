"""An environment whose simulator is missing here: the worker must not lease its task."""

from __future__ import annotations

import simulator_that_is_not_installed  # noqa: F401


def make_env(**_: object) -> None:
    raise AssertionError("never built")
