"""Repository of API tokens (stored as digests) and the dashboard's sign-in sessions.

Same conventions as every module of :mod:`adservice.repository` (an open session,
keyword-only arguments, domain errors, rows out).
"""

from __future__ import annotations

from datetime import datetime

import sqlalchemy as sa
from sqlalchemy.orm import Session

from adservice.errors import NotFoundError
from adservice.models import SessionRow, TokenRow, utcnow


def create_token(session: Session, *, name: str, role: str, digest: str) -> TokenRow:
    row = TokenRow(name=name, role=role, token_sha256=digest)
    session.add(row)
    session.flush()
    return row


def find_token(session: Session, *, digest: str) -> TokenRow | None:
    return session.scalars(
        sa.select(TokenRow).where(TokenRow.token_sha256 == digest, TokenRow.revoked_at.is_(None))
    ).one_or_none()


def list_tokens(session: Session) -> list[TokenRow]:
    return list(session.scalars(sa.select(TokenRow).order_by(TokenRow.id)))


def revoke_token(session: Session, *, token_id: int) -> TokenRow:
    row = session.get(TokenRow, token_id)
    if row is None:
        raise NotFoundError(f"token {token_id} not found")
    if row.revoked_at is None:
        row.revoked_at = utcnow()
    return row


# --- dashboard sessions -----------------------------------------------------------------


def create_session(
    session: Session, *, digest: str, token_id: int, csrf_token: str, expires_at: datetime
) -> SessionRow:
    row = SessionRow(
        id_sha256=digest, token_id=token_id, csrf_token=csrf_token, expires_at=expires_at
    )
    session.add(row)
    session.flush()
    return row


def find_session(session: Session, *, digest: str) -> tuple[SessionRow, TokenRow] | None:
    """A live sign-in and its token (none once expired or once the token is revoked)."""
    found = session.execute(
        sa.select(SessionRow, TokenRow)
        .join(TokenRow, TokenRow.id == SessionRow.token_id)
        .where(
            SessionRow.id_sha256 == digest,
            SessionRow.expires_at > utcnow(),
            TokenRow.revoked_at.is_(None),
        )
    ).one_or_none()
    return None if found is None else (found[0], found[1])


def delete_session(session: Session, *, digest: str) -> None:
    """Sign out; expired sign-ins go with it."""
    session.execute(
        sa.delete(SessionRow).where(
            sa.or_(SessionRow.id_sha256 == digest, SessionRow.expires_at <= utcnow())
        )
    )
