"""The body of every error answer."""

from __future__ import annotations

from typing import Any

from pydantic import (
    BaseModel,
    Field,
)


class ErrorBody(BaseModel):
    """Every 4xx/5xx answer: a machine-readable code and a message naming what is wrong."""

    error: str
    detail: Any
    problems: list[str] | None = Field(default=None, description="each invalid field, named")
