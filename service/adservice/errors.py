"""Domain errors. They know nothing of HTTP: ``adservice.app`` maps them to status codes."""

from __future__ import annotations


class DomainError(Exception):
    code = "error"

    def __init__(self, detail: str, *, problems: list[str] | None = None) -> None:
        super().__init__(detail)
        self.detail = detail
        self.problems = problems
        """Each invalid field, named (``ErrorBody.problems``)."""


class NotFoundError(DomainError):
    code = "not_found"


class ConflictError(DomainError):
    code = "conflict"


class LeaseLostError(ConflictError):
    code = "lease_lost"


class StudyConfigError(ConflictError):
    """A stored study's settings cannot be used (stored before they were checked)."""

    code = "invalid_study"


class ProposalFailedError(ConflictError):
    """A study's proposal raised (a model fit, a bug, memory): recorded on the study,
    whose proposals then back off; other studies are untouched."""

    code = "proposal_failed"


class OverQuotaError(ConflictError):
    """An owner's studies store as many bytes as its storage quota allows: no new trial
    is made for it (an upload past the quota is a ``TooLargeError``)."""

    code = "over_quota"


class InvalidError(DomainError):
    """A request naming a bad value; its answer always lists ``problems`` (the detail
    alone when none are given), as request validation's answers do."""

    code = "invalid"

    def __init__(self, detail: str, *, problems: list[str] | None = None) -> None:
        super().__init__(detail, problems=problems or [detail])


class TooLargeError(DomainError):
    code = "too_large"


class BusyError(DomainError):
    """A bounded pool of the server's is full: nothing was done, and the same request
    may be sent again after ``retry_after`` seconds."""

    code = "busy"

    def __init__(self, detail: str, *, retry_after: int) -> None:
        super().__init__(detail)
        self.retry_after = retry_after


class RateLimitedError(BusyError):
    """A token sent more requests than its rate allows (``adservice.rates``): nothing was
    done, and the same request may be sent again after ``retry_after`` seconds."""

    code = "rate_limited"


class ClientGoneError(DomainError):
    """The request's client disconnected before its answer: the work it started was
    stopped and nothing was stored (no one reads the answer)."""

    code = "client_gone"


class UnauthorizedError(DomainError):
    code = "unauthorized"


class ForbiddenError(DomainError):
    code = "forbidden"
