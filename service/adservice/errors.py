"""Domain errors. They know nothing of HTTP: ``adservice.app`` maps them to status codes."""

from __future__ import annotations


class DomainError(Exception):
    code = "error"

    def __init__(self, detail: str) -> None:
        super().__init__(detail)
        self.detail = detail


class NotFoundError(DomainError):
    code = "not_found"


class ConflictError(DomainError):
    code = "conflict"


class LeaseLostError(ConflictError):
    code = "lease_lost"


class InvalidError(DomainError):
    code = "invalid"


class TooLargeError(DomainError):
    code = "too_large"


class UnauthorizedError(DomainError):
    code = "unauthorized"


class ForbiddenError(DomainError):
    code = "forbidden"
