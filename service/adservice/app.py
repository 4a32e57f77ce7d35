"""The FastAPI application factory: routers, error mapping, migrations, lease sweeper."""

from __future__ import annotations

import logging
import re
import sys
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.middleware.cors import CORSMiddleware

from adclient import __version__
from adclient.errors import quoted
from adclient.plugins import catalogue
from adclient.schemas import MAX_JSON_DEPTH, ErrorBody
from adservice.api.routes import (
    artifacts,
    dashboard,
    docs,
    health,
    jobs,
    learners,
    metrics,
    notes,
    reports,
    session,
    shared_controllers,
    studies,
    study_trials,
    tasks,
    trials,
    workers,
)
from adservice.artifacts import ArtifactStore
from adservice.auth import Authentication, PrincipalCache
from adservice.creations import CreationBudget, CreationPool
from adservice.db import Database, upgrade_to_head
from adservice.errors import (
    BusyError,
    ClientGoneError,
    ConflictError,
    DomainError,
    ForbiddenError,
    InvalidError,
    NotFoundError,
    RateLimitedError,
    TooLargeError,
    UnauthorizedError,
)
from adservice.expansions import ExpansionPool, UrdfLimits
from adservice.limits import BodyLimits
from adservice.locks import StudyLocks
from adservice.metrics import install_metrics
from adservice.proposal_runner import AskBudget, ProposalRunner, available_cores
from adservice.rates import TokenRates
from adservice.repository import leases as lease_repo
from adservice.repository import promotion as promotion_repo
from adservice.security import BrowserEdge
from adservice.services.configs import StudyConfigs
from adservice.services.proposal_failures import Backoff
from adservice.services.studies import warm_up as warm_up_creation_checks
from adservice.services.trials import Proposing
from adservice.settings import Settings, get_settings

log = logging.getLogger("adservice")

STATIC_DIR = Path(__file__).parent / "static"
SWITCH_INTERVAL_SECONDS = 0.001
"""How often a computing thread of the server yields the interpreter
(``sys.setswitchinterval``): against 5 ms, another user's reads beside a flood of large
creations wait half as long (bench/RESULTS.md, "Noisy neighbour")."""

STATUS_BY_ERROR: dict[type[DomainError], int] = {
    NotFoundError: 404,
    ConflictError: 409,
    InvalidError: 422,
    TooLargeError: 413,
    BusyError: 503,
    RateLimitedError: 429,
    UnauthorizedError: 401,
    ForbiddenError: 403,
    ClientGoneError: 499,  # nginx's "client closed request": logged, never read
}


def _status_for(error: DomainError) -> int:
    for cls in type(error).__mro__:
        if cls in STATUS_BY_ERROR:
            return STATUS_BY_ERROR[cls]
    return 400


def _given(item: Any) -> str:
    """What a field of the wrong JSON type got, where the type is the mistake: a
    quoted number or a truth value (a YAML loader reads ``1e-3`` as text)."""
    given = item.get("input")
    if not str(item.get("type", "")).endswith("_type") or not isinstance(given, str | bool):
        return ""
    if isinstance(given, bool):
        return f" (got {str(given).lower()})"
    return f" (got the text {quoted(given)})"


def _field_path(location: tuple[int | str, ...]) -> str:
    parts = [str(part) for part in location if part not in ("body",)]
    return ".".join(parts) or "body"


ERROR_RESPONSES = {
    400: "Malformed request",
    401: "No valid bearer token",
    403: "The token's role does not allow this",
    404: "No such study, trial or artifact",
    405: "Method not allowed on this path",
    409: "Conflicts with the current state (finished trial, lost lease, full study)",
    413: "Body too large",
    415: "A change sent with neither a JSON body nor the X-Activedesign-Client header",
    422: "Invalid field; the detail names it",
    431: "Request line and headers longer than AD_MAX_HEADER_BYTES (a long query string)",
    503: "Busy (a queue of template expansions or study creations is full): nothing was done; "
    "see Retry-After",
}
PLAIN_TEXT_ERRORS = {431}
"""Answered by the server's protocol layer before any route, in plain text."""


def document_error_bodies(app: FastAPI) -> None:
    """Every operation documents its 4xx answers as ``ErrorBody``, which is what the
    handlers below send (FastAPI's default 422 schema would be a lie)."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema:
            return app.openapi_schema
        schema = build()
        components = schema.setdefault("components", {}).setdefault("schemas", {})
        components["ErrorBody"] = ErrorBody.model_json_schema(
            ref_template="#/components/schemas/{model}"
        )
        for component in ("HTTPValidationError", "ValidationError"):
            components.pop(component, None)
        ref = {"$ref": "#/components/schemas/ErrorBody"}
        for operations in schema["paths"].values():
            for operation in operations.values():
                responses = operation.setdefault("responses", {})
                for status, description in ERROR_RESPONSES.items():
                    plain = {"text/plain": {"schema": {"type": "string"}}}
                    content: dict[str, Any] = {"application/json": {"schema": ref}}
                    if status in PLAIN_TEXT_ERRORS:
                        content = plain
                    elif status == 400:  # uvicorn answers malformed HTTP itself, in plain text
                        content |= plain
                    responses[str(status)] = {"description": description, "content": content}
        app.openapi_schema = schema
        return schema

    app.openapi = openapi  # type: ignore[method-assign]


def _allowed_methods(app: FastAPI, path: str) -> list[str]:
    """The methods the published API serves at ``path`` (for 405's ``Allow``)."""
    methods: set[str] = set()
    for template, operations in app.openapi()["paths"].items():
        pattern = re.sub(r"\\{[^/]+?\\}", "[^/]+", re.escape(template))
        if re.fullmatch(pattern, path):
            methods |= {method.upper() for method in operations}
    if "GET" in methods:
        methods.add("HEAD")
    return sorted(methods)


TOO_DEEP_BODY = (
    "body: objects and arrays nest deeper than the JSON parser reads (a free JSON field "
    f"takes at most {MAX_JSON_DEPTH} levels)"
)


def _unread_body(cause: BaseException | None) -> str | None:
    """Why the JSON parser could not read a body, for the causes a client can mend:
    nesting past the parser's stack, bytes that are not UTF-8, and an integer longer
    than Python converts (``sys.get_int_max_str_digits``); None for any other."""
    if isinstance(cause, RecursionError):
        return TOO_DEEP_BODY
    if isinstance(cause, UnicodeDecodeError):
        return f"body: not UTF-8 text (byte {cause.start} cannot be decoded)"
    if isinstance(cause, ValueError) and "integer string conversion" in str(cause):
        return (
            "body: a number has more digits than the JSON parser reads "
            f"(at most {sys.get_int_max_str_digits()})"
        )
    return None


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, error: StarletteHTTPException) -> JSONResponse:
        unread = _unread_body(error.__cause__)  # FastAPI's "error parsing the body"
        if unread is not None:
            return JSONResponse(
                {"error": "invalid", "detail": unread, "problems": [unread]}, status_code=422
            )
        headers = dict(error.headers or {})
        if error.status_code == 405:
            headers["Allow"] = ", ".join(_allowed_methods(app, request.url.path))
        code = {404: "not_found", 405: "method_not_allowed"}.get(error.status_code, "error")
        return JSONResponse(
            {"error": code, "detail": str(error.detail)},
            status_code=error.status_code,
            headers=headers,
        )

    @app.exception_handler(DomainError)
    async def domain_error(_request: Request, error: DomainError) -> JSONResponse:
        status = _status_for(error)
        headers = {"WWW-Authenticate": "Bearer"} if status == 401 else None
        if isinstance(error, BusyError):
            headers = {"Retry-After": str(error.retry_after)}
        body: dict[str, Any] = {"error": error.code, "detail": error.detail}
        if error.problems:
            body["problems"] = error.problems
        return JSONResponse(body, status_code=status, headers=headers)

    @app.exception_handler(RequestValidationError)
    async def validation_error(_request: Request, error: RequestValidationError) -> JSONResponse:
        problems = [
            f"{_field_path(tuple(item.get('loc', ())))}: "
            f"{str(item.get('msg', 'invalid')).removeprefix('Value error, ')}{_given(item)}"
            for item in error.errors()
        ]
        return JSONResponse(
            {"error": "invalid", "detail": "; ".join(problems), "problems": problems},
            status_code=422,
        )


def _sweep_leases(db: Database, interval: float, stop: threading.Event) -> None:
    """Every ``interval``: expired leases back to the queue, paused trials of spent
    studies ended (pruned), and studies whose trials all ended finished, so a study
    completes even when no worker asks for work."""
    while not stop.wait(interval):
        try:
            with db.write() as session:
                expired = lease_repo.expire_leases(session)
                settled = promotion_repo.settle_spent_studies(session)
                finished = promotion_repo.finish_done_studies(session)
            if finished:
                log.info("finished %d study(ies) whose last tell left them running", finished)
            if expired:
                log.info("returned %d expired lease(s) to the queue", expired)
            if settled:
                log.info("ended %d paused trial(s) of spent studies as pruned", settled)
        except Exception:  # keep sweeping: a transient database error must not end it
            log.exception("lease sweep failed")


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or get_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # A thread that computes (a body's checks, a proposal's Python) hands the
        # interpreter back to the event loop every millisecond, not Python's 5: a request
        # waits for the loop at most that long per hand-over (docs/server.md)
        sys.setswitchinterval(SWITCH_INTERVAL_SECONDS)
        # First, while the server is one thread: the helper that forks creations' children
        # (it ends with this process, however the start below goes)
        create_memory = settings.create_memory_mb
        creations = CreationPool(
            settings.create_processes,
            settings.create_queue,
            budget=CreationBudget(
                settings.create_seconds,
                None if create_memory is None else int(create_memory * 2**20),
            ),
            warm_up=warm_up_creation_checks,
            per_owner=settings.create_per_owner,
        )
        creations.start()
        app.state.creations = creations
        upgrade_to_head(settings.database_url)
        for key, reason in sorted(catalogue().broken.items()):
            log.warning("plugin %s does not load: %s", key, reason)
        db = Database(settings.database_url)
        app.state.db = db
        app.state.settings = settings
        memory = settings.ask_memory_mb
        runner = ProposalRunner(
            settings.proposal_threads or available_cores(),
            AskBudget(settings.ask_seconds, None if memory is None else int(memory * 2**20)),
        )
        backoff = Backoff(settings.proposal_backoff_seconds, settings.proposal_backoff_max_seconds)
        expansions = ExpansionPool(
            settings.expand_threads,
            settings.expand_queue,
            UrdfLimits(
                settings.max_urdf_bytes,
                settings.max_ask_urdf_bytes,
                settings.max_study_urdf_bytes,
                settings.lease_expand_seconds,
            ),
            per_owner=settings.expand_per_owner,
        )
        app.state.proposing = Proposing(
            db,
            StudyConfigs(db),
            StudyLocks(),
            runner,
            backoff,
            expansions,
            storage_quota=settings.owner_storage_bytes,
        )
        app.state.principals = PrincipalCache()
        app.state.rates = TokenRates(
            requests_per_second=settings.token_requests_per_second,
            request_burst=settings.token_request_burst,
            creations_per_minute=settings.token_creations_per_minute,
            creation_burst=settings.token_creation_burst,
        )
        app.state.artifacts = ArtifactStore(settings.resolved_artifact_dir())
        stop = threading.Event()
        sweeper = threading.Thread(
            target=_sweep_leases, args=(db, settings.sweep_seconds, stop), daemon=True
        )
        sweeper.start()
        try:
            yield
        finally:
            creations.shutdown()  # kills the creations' children: nothing half-stored
            stop.set()
            sweeper.join(timeout=5)
            runner.shutdown()
            expansions.shutdown()
            db.dispose()

    app = FastAPI(
        title="activedesign",
        version=__version__,
        description="Automatic robot design: ask/tell Bayesian optimisation, simulation workers.",
        lifespan=lifespan,
        docs_url=None,  # served from the package by the docs router
        redoc_url=None,
    )
    install_error_handlers(app)
    document_error_bodies(app)
    # Added last runs first: the edge (host, cross-site guard, security headers on every
    # answer), CORS, the body's size and deadline, and who is calling before any route
    # parses a body.
    app.add_middleware(Authentication)
    app.add_middleware(
        BodyLimits,
        limit=settings.max_body_bytes,
        artifact_limit=settings.max_artifact_bytes,
        timeout=settings.body_timeout,
    )
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["GET", "POST", "PUT", "PATCH", "DELETE"],
            allow_headers=["Authorization", "Content-Type", "X-Activedesign-Client"],
            expose_headers=["X-Total-Count"],
        )
    app.add_middleware(BrowserEdge, allowed_hosts=settings.resolved_allowed_hosts())
    install_metrics(app)
    # The hot routes first: a request is matched against the routes in this order.
    for module in (
        trials,
        studies,
        study_trials,
        jobs,
        reports,
        artifacts,
        shared_controllers,
        dashboard,
        notes,
        session,
        tasks,
        learners,
        workers,
        health,
        metrics,
        docs,
    ):
        app.include_router(module.router)

    @app.api_route(
        "/api/{rest:path}",
        methods=["GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"],
        include_in_schema=False,
    )
    def unknown_api_path(request: Request, rest: str) -> None:
        """Under /api, a path no route serves is a JSON 404, and a known path with the
        wrong method a 405 with ``Allow``, never the dashboard's static files."""
        allowed = _allowed_methods(app, request.url.path)
        if allowed:
            raise StarletteHTTPException(405, headers={"Allow": ", ".join(allowed)})
        raise StarletteHTTPException(404, f"no API path {request.url.path}")

    if (STATIC_DIR / "index.html").is_file():
        app.mount("/", StaticFiles(directory=STATIC_DIR, html=True), name="dashboard")
    return app
