"""The dashboard's sign-in: a token is exchanged once for an HttpOnly, SameSite=Strict
session cookie, so the page never holds the token (no script can read it, no URL carries
it); changes made with the cookie need the session's CSRF token too."""

from __future__ import annotations

import secrets
from datetime import timedelta

from fastapi import APIRouter, Depends, Request, Response

from adclient.schemas import SessionInfo, SignInRequest
from adservice.api.deps import DatabaseDep, SettingsDep
from adservice.auth import SESSION_COOKIE, authenticate, new_session_id, session_id_of, token_digest
from adservice.errors import ForbiddenError, UnauthorizedError
from adservice.models import utcnow
from adservice.principals import Principal, Role
from adservice.repository import tokens as token_repo
from adservice.security import from_own_origin


async def own_pages_only(request: Request, settings: SettingsDep) -> None:
    """The session answers only the server's own pages: another site's page must not
    learn the CSRF token, nor sign the visitor in or out (403 naming why)."""
    if not from_own_origin(request.headers, request.url.scheme, settings.public_url):
        raise ForbiddenError(
            "the session answers only this server's own pages: the request's Origin "
            "(or Sec-Fetch-Site) names another site"
        )


router = APIRouter(
    prefix="/api/v1/session", tags=["session"], dependencies=[Depends(own_pages_only)]
)


def _info(principal: Principal, *, auth: bool) -> SessionInfo:
    return SessionInfo(
        auth=auth,
        signed_in=True,
        role=principal.role.value,
        name=principal.name or None,
        csrf_token=principal.csrf_token,
    )


@router.get("")
async def who_am_i(request: Request, settings: SettingsDep) -> SessionInfo:
    """The caller by bearer token or sign-in cookie; ``signed_in: false`` for nobody."""
    try:
        principal = await authenticate(request.scope)
    except UnauthorizedError:
        return SessionInfo(auth=True, signed_in=False)
    return _info(principal, auth=bool(settings.auth))


@router.post("")
def sign_in(
    body: SignInRequest,
    request: Request,
    response: Response,
    db: DatabaseDep,
    settings: SettingsDep,
) -> SessionInfo:
    """Exchange a token for a session cookie (401 for an unknown or revoked token)."""
    if not settings.auth:
        return SessionInfo(auth=False, signed_in=True, role="admin")
    session_id = new_session_id()
    csrf_token = secrets.token_urlsafe(24)
    lifetime = timedelta(hours=settings.session_hours)
    with db.write() as session:
        token = token_repo.find_token(session, digest=token_digest(body.token))
        if token is None:
            raise UnauthorizedError("unknown or revoked token")
        token_repo.create_session(
            session,
            digest=token_digest(session_id),
            token_id=token.id,
            csrf_token=csrf_token,
            expires_at=utcnow() + lifetime,
        )
        principal = Principal(
            role=Role(token.role), token_id=token.id, name=token.name, csrf_token=csrf_token
        )
    response.set_cookie(
        SESSION_COOKIE,
        session_id,
        max_age=int(lifetime.total_seconds()),
        path="/",
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",
    )
    return _info(principal, auth=True)


@router.delete("", status_code=204)
def sign_out(request: Request, db: DatabaseDep) -> Response:
    """End the browser's session (the cookie's, if any) and clear the cookie."""
    session_id = session_id_of(dict(request.scope["headers"]))
    if session_id is not None:
        digest = token_digest(session_id)
        with db.write() as session:
            token_repo.delete_session(session, digest=digest)
        request.app.state.principals.forget("s:" + digest)
    response = Response(status_code=204)
    response.delete_cookie(SESSION_COOKIE, path="/", httponly=True, samesite="strict")
    return response
