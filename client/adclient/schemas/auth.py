"""Signing in to the dashboard, and who the caller is."""

from __future__ import annotations

from pydantic import (
    BaseModel,
    Field,
)

from adclient.schemas.common import NO_NUL_PATTERN
from adclient.strict import StrictInput


class SignInRequest(StrictInput):
    """The dashboard's sign-in: the token is sent once and never stored by the page."""

    token: str = Field(min_length=1, max_length=256, pattern=NO_NUL_PATTERN)


class SessionInfo(BaseModel):
    """Who the caller is (``GET /api/v1/session``): what the dashboard shows and needs."""

    auth: bool = Field(description="whether the server requires a token")
    signed_in: bool
    role: str | None = None
    name: str | None = None
    csrf_token: str | None = Field(
        default=None,
        description="with a sign-in cookie, send this in X-CSRF-Token on every change",
    )
