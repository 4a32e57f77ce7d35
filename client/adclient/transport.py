"""The SDK's HTTP transport: one connection to a server, retries with backoff, and
errors turned into :mod:`adclient.errors` exceptions.

Why the retries are safe: a request that never reached the server (connection
refused, connect timeout) is always retried; a 5xx or 429 answer means the server
rolled the request back, so it is retried too. A request whose answer was lost after
it was sent (read timeout, dropped connection) is retried only where repeating it is
harmless: reads, artifact uploads, heartbeats and tells (the server accepts a repeated
identical tell). ``create_study``, ``ask`` and ``lease`` are not repeated in that case
(they would create or lease a second time); they raise :class:`Unavailable` instead.
"""

from __future__ import annotations

import functools
import math
import os
import random
import ssl
import time
from collections.abc import Mapping
from typing import Any, Self

import httpx

from adclient import __version__
from adclient.errors import ApiError, Unavailable, error_class

API = "/api/v1"
DEFAULT_TIMEOUT = 30.0
DEFAULT_RETRIES = 5
DEFAULT_BACKOFF = 0.2
DEFAULT_MAX_BACKOFF = 5.0

CLIENT_HEADER = "X-Activedesign-Client"


def tls_context(verify: bool | str) -> ssl.SSLContext:
    """The certificate check for ``verify`` (as :class:`Transport` takes it), one per
    process: loading a CA bundle costs about 30 ms of CPU, which a process that makes
    many clients (a worker pool, a script per trial, the tests) paid for each one."""
    return _tls_context(verify, os.environ.get("SSL_CERT_FILE"), os.environ.get("SSL_CERT_DIR"))


@functools.cache
def _tls_context(verify: bool | str, cert_file: str | None, cert_dir: str | None) -> ssl.SSLContext:
    if isinstance(verify, str):
        return ssl.create_default_context(cafile=verify)
    return httpx.create_ssl_context(verify=verify)  # SSL_CERT_FILE and _DIR, else certifi


"""Sent with every request: a header a cross-site page cannot set without the server's
leave, so the server accepts state changes only from clients that send it (or JSON)."""


class Transport:
    """A connection to one activedesign server.

    ``url`` is the server's base URL (``http://host:port``). ``token`` is sent as
    ``Authorization: Bearer <token>``. ``timeout`` bounds each attempt in seconds.
    ``retries`` is how many times a failed attempt is repeated (see the module notes
    for which failures), waiting ``backoff * 2**n`` seconds (with jitter, at most
    ``max_backoff``, or the server's ``Retry-After``) before repeat ``n``.

    Use it as a context manager, or call :meth:`close`.
    """

    def __init__(
        self,
        url: str,
        token: str | None = None,
        *,
        timeout: float = DEFAULT_TIMEOUT,
        retries: int = DEFAULT_RETRIES,
        backoff: float = DEFAULT_BACKOFF,
        max_backoff: float = DEFAULT_MAX_BACKOFF,
        verify: bool | str = True,
    ) -> None:
        """``verify``: check an https server's certificate against the system's CAs (True),
        against the CA bundle file at this path (a private or self-signed CA), or not at
        all (False)."""
        if retries < 0:
            raise ValueError("retries must be >= 0")
        self.url = url.rstrip("/")
        self.retries = retries
        self.backoff = backoff
        self.max_backoff = max_backoff
        headers = {
            "User-Agent": f"adclient/{__version__}",
            "Accept": "application/json",
            CLIENT_HEADER: __version__,
        }
        if token:
            headers["Authorization"] = f"Bearer {token}"
        self._http = httpx.Client(
            base_url=self.url,
            headers=headers,
            timeout=httpx.Timeout(timeout, connect=min(timeout, 10.0)),
            verify=tls_context(verify),
        )

    # -- lifecycle -------------------------------------------------------------------

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.url!r})"

    # -- transport -------------------------------------------------------------------

    def request(
        self,
        method: str,
        path: str,
        *,
        json_body: Any = None,
        content: bytes | None = None,
        headers: Mapping[str, str] | None = None,
        params: Mapping[str, Any] | None = None,
        idempotent: bool | None = None,
    ) -> httpx.Response:
        """Send one request with retries; return the 2xx/3xx response or raise an ApiError.

        ``idempotent`` (default: true for GET, HEAD, PUT and DELETE) says whether a
        request whose answer was lost may be sent again.
        """
        if idempotent is None:
            idempotent = method.upper() in {"GET", "HEAD", "PUT", "DELETE"}
        kwargs: dict[str, Any] = {"headers": headers, "params": params}
        if json_body is not None:
            kwargs["json"] = json_body
        if content is not None:
            kwargs["content"] = content
        where = f"{method} {path}"
        failure: ApiError
        for attempt in range(self.retries + 1):
            delay = self._delay(attempt)
            try:
                response = self._http.request(method, path, **kwargs)
            except (httpx.ConnectError, httpx.ConnectTimeout, httpx.PoolTimeout) as exc:
                failure = Unavailable(
                    None,
                    "unreachable",
                    f"cannot reach server at {self.url} ({_reason(exc)})",
                    method=method,
                    url=path,
                )
            except httpx.TransportError as exc:
                failure = Unavailable(
                    None,
                    "no_answer",
                    f"no answer from server at {self.url} to {where} ({_reason(exc)})",
                    method=method,
                    url=path,
                )
                if not idempotent:
                    raise failure from exc
            else:
                if response.status_code < 400:
                    return response
                failure = self._error(response, method, path)
                if not _retryable_status(response.status_code):
                    raise failure
                delay = _retry_after(response, default=delay, cap=self.max_backoff)
            if attempt < self.retries:
                time.sleep(delay)
        raise failure

    def _delay(self, attempt: int) -> float:
        """Exponential backoff with 'equal jitter': between half and all of the step."""
        step = min(self.max_backoff, self.backoff * (2**attempt))
        return step * (0.5 + random.random() / 2)

    @staticmethod
    def _error(response: httpx.Response, method: str, path: str) -> ApiError:
        code: str | None = None
        detail: Any = None
        try:
            body = response.json()
        except ValueError:
            body = None
        if isinstance(body, dict) and ("error" in body or "detail" in body):
            code = body.get("error") if isinstance(body.get("error"), str) else None
            detail = body.get("detail")
        elif response.text:
            detail = response.text[:500]
        if detail is None or detail == "":
            detail = f"HTTP {response.status_code} {response.reason_phrase}".strip()
        cls = error_class(response.status_code)
        return cls(response.status_code, code, detail, method=method, url=path)

    def _get_json(self, path: str, params: Mapping[str, Any] | None = None) -> Any:
        return self.request("GET", path, params=params).json()


def _retryable_status(status_code: int) -> bool:
    return status_code >= 500 or status_code == 429


def _retry_after(response: httpx.Response, *, default: float, cap: float) -> float:
    header = response.headers.get("Retry-After")
    if header is None:
        return default
    try:
        seconds = float(header)
    except ValueError:
        return default
    if not math.isfinite(seconds) or seconds < 0:
        return default
    return min(seconds, cap)


def _reason(exc: Exception) -> str:
    text = str(exc).strip()
    return text or type(exc).__name__
