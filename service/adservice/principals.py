"""Who acts, as the service layer and repository check it: a role and the token behind it.

Kept apart from ``adservice.auth`` (which finds the principal of an HTTP request) so the
repository can check lease holders and study owners without importing the web layer.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from adservice.errors import ForbiddenError


class Role(StrEnum):
    reader = "reader"
    worker = "worker"
    user = "user"
    admin = "admin"


RANK = {Role.reader: 0, Role.worker: 1, Role.user: 2, Role.admin: 3}


@dataclass(frozen=True)
class Principal:
    role: Role
    token_id: int | None
    """None with auth off: callers are not told apart, so only ``worker_id`` is checked."""
    name: str = ""
    csrf_token: str | None = None
    """Set when the caller signed in through the dashboard (a cookie), not a header."""

    @property
    def is_admin(self) -> bool:
        return self.role == Role.admin

    @property
    def checked(self) -> bool:
        """Whether leases and ownership are checked against this caller's token."""
        return self.token_id is not None and not self.is_admin

    @property
    def leased_owner(self) -> int | None:
        """The token whose studies alone this caller's leases serve: a ``user``'s own,
        the studies it may write; None for a worker or an admin, whose leases serve every
        managed study, and with auth off."""
        return self.token_id if self.checked and self.role == Role.user else None

    def may_manage(self, owner_token_id: int | None) -> bool:
        """Whether this caller may ask, tell, stop or delete a study owned by that token."""
        return not self.checked or (self.role == Role.user and self.token_id == owner_token_id)


def check_manager(
    caller: Principal, *, study_id: int, owner_token_id: int | None, owner_name: str | None
) -> None:
    """Asking, telling, stopping or deleting a study is for its owner (or an admin)."""
    if not caller.may_manage(owner_token_id):
        whose = f"token {owner_name!r}" if owner_name else "another token"
        raise ForbiddenError(
            f"study {study_id} belongs to {whose}: only its owner or an admin may change it"
        )


OPEN_ADMIN = Principal(role=Role.admin, token_id=None)
"""Every caller when auth is off."""
