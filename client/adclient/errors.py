"""The SDK's exceptions: one small hierarchy, so callers catch what they can act on.

::

    ActiveDesignError            anything the SDK raises on purpose
    └── ApiError                 the server said no, or could not be reached
        ├── Invalid              400 / 422: the request names a bad field (also a ValueError)
        ├── Unauthorized         401: no token, or an unknown one
        ├── Forbidden            403: the token's role may not do this
        ├── NotFound             404: unknown study, trial, artifact...
        ├── Conflict             409: contradicts the stored state (e.g. lease lost)
        ├── PayloadTooLarge      413: body or artifact over the server's limit
        ├── Unavailable          network error, or 5xx still failing after the retries
        └── UnreadableJob        a leased job names a field this SDK does not know

An :class:`ApiError` carries the HTTP ``status_code`` (``None`` when no answer came
back, or when the SDK rejected the request before sending it), the server's
machine-readable ``code`` and its human ``detail`` (the ``{"error": code, "detail":
message}`` body of every 4xx/5xx answer).
"""

from __future__ import annotations

from typing import Any


def quoted(value: Any, most: int = 60) -> str:
    """``value`` as an error message quotes it: its repr, cut past ``most`` characters,
    so a 400-digit number or a 100,000-character name cannot flood the message."""
    text = repr(value)
    return text if len(text) <= most else f"{text[:most]}... ({len(text)} characters)"


class ActiveDesignError(Exception):
    """Base of every exception the SDK raises on purpose."""


class ApiError(ActiveDesignError):
    """A request that did not succeed: an error answer, or no answer at all."""

    default_code = "error"

    def __init__(
        self,
        status_code: int | None,
        code: str | None = None,
        detail: Any = None,
        *,
        method: str | None = None,
        url: str | None = None,
    ) -> None:
        self.status_code = status_code
        self.code = code or self.default_code
        self.detail = detail
        self.method = method
        self.url = url
        super().__init__(self.message)

    @property
    def message(self) -> str:
        """One line for a human: the detail, flattened when the server sent a structure."""
        return format_detail(self.detail) or self.code

    def __str__(self) -> str:
        if self.status_code is None:
            return self.message
        return f"{self.message} (HTTP {self.status_code}, {self.code})"

    def __reduce__(self) -> tuple[Any, ...]:  # picklable across worker processes
        return (
            _rebuild,
            (type(self), self.status_code, self.code, self.detail, self.method, self.url),
        )


def _rebuild(
    cls: type[ApiError],
    status_code: int | None,
    code: str,
    detail: Any,
    method: str | None,
    url: str | None,
) -> ApiError:
    return cls(status_code, code, detail, method=method, url=url)


class Invalid(ApiError, ValueError):
    """400 or 422: the request is malformed or names a bad value; nothing was stored."""

    default_code = "invalid"


class Unauthorized(ApiError):
    """401: the server needs a (valid) bearer token."""

    default_code = "unauthorized"


class Forbidden(ApiError):
    """403: the token is valid but its role may not do this."""

    default_code = "forbidden"


class NotFound(ApiError, LookupError):
    """404: the study, trial or artifact does not exist (or, for ``best``, nothing is complete)."""

    default_code = "not_found"


class Conflict(ApiError):
    """409: the request contradicts stored state (a different tell, a lost lease)."""

    default_code = "conflict"


class PayloadTooLarge(ApiError):
    """413: the body or artifact is over the server's size limit."""

    default_code = "too_large"


class Unavailable(ApiError):
    """The server could not be reached, or kept answering 5xx after every retry."""

    default_code = "unavailable"


class UnreadableJob(ApiError):
    """A job was leased (HTTP 200) that this SDK's schemas cannot read: the server is
    newer and the study uses a setting this version does not know. ``trial_id`` is the
    leased trial's (``None`` when the answer does not name one), so a worker can tell
    it failed and say why (docs/worker.md, "Workers older than the server")."""

    default_code = "unreadable_job"

    def __init__(self, trial_id: int | None, detail: str) -> None:
        super().__init__(200, self.default_code, detail)
        self.trial_id = trial_id

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (self.trial_id, self.detail))


_BY_STATUS: dict[int, type[ApiError]] = {
    400: Invalid,
    401: Unauthorized,
    403: Forbidden,
    404: NotFound,
    409: Conflict,
    413: PayloadTooLarge,
    422: Invalid,
}


def error_class(status_code: int) -> type[ApiError]:
    """The exception class for an HTTP error status."""
    if status_code >= 500:
        return Unavailable
    return _BY_STATUS.get(status_code, ApiError)


def format_detail(detail: Any) -> str:
    """Flatten a server ``detail`` into one line.

    FastAPI's validation errors arrive as a list of ``{"loc": [...], "msg": ...}``;
    they become ``body.count: Input should be less than or equal to 64; ...``.
    """
    if detail is None:
        return ""
    if isinstance(detail, str):
        return " ".join(detail.split())
    if isinstance(detail, list):
        return "; ".join(part for part in (_format_item(item) for item in detail) if part)
    if isinstance(detail, dict):
        return _format_item(detail)
    return str(detail)


def _format_item(item: Any) -> str:
    if isinstance(item, dict) and "msg" in item:
        loc = item.get("loc") or []
        where = ".".join(str(part) for part in loc)
        msg = " ".join(str(item["msg"]).split())
        return f"{where}: {msg}" if where else msg
    if isinstance(item, dict):
        return ", ".join(f"{key}: {format_detail(value)}" for key, value in item.items())
    return format_detail(item)
