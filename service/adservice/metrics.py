"""Prometheus metrics, right with several servers on one database.

Gauges of the database's state (trials by study and state, leases held, the queue) are
read from the database at each scrape, in one statement: every replica reports the same
truth, and a query takes each series once over the replicas (``max``). Counters and
histograms (tells, ask seconds, request durations) count this process's requests in a
registry of its own; Prometheus scrapes every pod and sums them. Neither needs
prometheus-client's multiprocess mode: ``adserver`` is one process.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from time import perf_counter

import sqlalchemy as sa
from fastapi import FastAPI
from prometheus_client import CollectorRegistry, Counter, Histogram, ProcessCollector
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.exposition import generate_latest
from prometheus_client.registry import Collector, Metric
from sqlalchemy.orm import Session
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from adclient.plugins import catalogue
from adclient.schemas import TrialState
from adservice.models import StudyRow, TrialRow, utcnow

TELL = ("POST", "/api/v1/trials/{trial_id}/tell")
ASK = ("POST", "/api/v1/studies/{study_id}/ask")
METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"})
"""Methods named in labels; any other is "other" (a client may send any token)."""
UNROUTED = "unrouted"
"""The route label of an answer no route gave: refused before routing (host, token, body
size) or a dashboard file."""
BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60)
"""Seconds: a tell takes about a millisecond, a model-based ask up to ``AD_ASK_SECONDS``."""

DATABASE_GAUGES: dict[str, tuple[str, tuple[str, ...]]] = {
    "activedesign_trials": ("Trials by study id and state.", ("study", "state")),
    "activedesign_leases_active": (
        "Trials leased to a worker now (an expired lease until the sweeper returns it).",
        (),
    ),
    "activedesign_queue_depth": (
        "Trials waiting for a worker, by task: queued trials of running managed studies "
        "plus the trials those studies may still propose (max_trials - n_trials), but not "
        "while a study's failed proposals back off.",
        ("task",),
    ),
    "activedesign_proposal_failures": (
        "Proposals of a study that failed in a row, by study id (0: its last succeeded).",
        ("study",),
    ),
    "activedesign_proposal_fallbacks": (
        "Candidates of a study that were Sobol points because a time or memory budget or a "
        "failed model stopped its proposer, by study id.",
        ("study",),
    ),
}
"""Name -> (help, labels) of the gauges read from the database (the k8s test checks the
ScaledObject's query against these)."""


class Metrics:
    """One app's per-process counters and histograms, in a registry of its own (so apps
    built in one process, as in tests, do not collide)."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        ProcessCollector(registry=self.registry)
        self.http_seconds = Histogram(
            "activedesign_http_request_duration_seconds",
            "HTTP requests of this process to their last byte, by route template and status.",
            ("method", "route", "status"),
            buckets=BUCKETS,
            registry=self.registry,
        )
        self.tells = Counter(
            "activedesign_tells",
            "Tells this process answered 200 (an identical retried tell counts again).",
            registry=self.registry,
        )
        self.ask_seconds = Histogram(
            "activedesign_ask_seconds",
            "Seconds this process took to answer an ask 200, proposals included.",
            buckets=BUCKETS,
            registry=self.registry,
        )
        self._children: dict[tuple[str, str, int], Histogram] = {}
        """Labelled histograms by key: ``labels()`` takes a lock and builds strings."""

    def observe(self, method: str, route: str, status: int, seconds: float) -> None:
        key = (method, route, status)
        child = self._children.get(key)
        if child is None:
            child = self._children[key] = self.http_seconds.labels(method, route, str(status))
        child.observe(seconds)
        if status == 200:
            if (method, route) == TELL:
                self.tells.inc()
            elif (method, route) == ASK:
                self.ask_seconds.observe(seconds)

    def render(self, session: Session, pools: Mapping[str, tuple[int, int]]) -> bytes:
        """The text exposition of one scrape: this process's metrics and its pools'
        places (``pools``: name -> (running, waiting)), then the database's."""
        return generate_latest(_Scrape(self.registry, session, pools))


class _Scrape(Collector):
    def __init__(
        self, registry: CollectorRegistry, session: Session, pools: Mapping[str, tuple[int, int]]
    ) -> None:
        self.registry = registry
        self.session = session
        self.pools = pools

    def collect(self) -> Iterator[Metric]:
        yield from self.registry.collect()
        places = GaugeMetricFamily(
            "activedesign_pool_places",
            "Places taken in this process's bounded pools (creations, expansions), by state: "
            "running, or waiting for a worker or for its owner's turn.",
            labels=["pool", "state"],
        )
        for pool, (running, waiting) in sorted(self.pools.items()):
            places.add_metric([pool, "running"], running)
            places.add_metric([pool, "waiting"], waiting)
        yield places
        yield from database_gauges(self.session)


_GAUGE_QUERY = (
    sa.select(
        StudyRow.id,
        StudyRow.state,
        StudyRow.task["name"].as_string(),
        StudyRow.max_trials,
        StudyRow.n_trials,
        StudyRow.proposal_failures,
        StudyRow.proposal_retry_at,
        StudyRow.proposal_fallbacks,
        TrialRow.state,
        sa.func.count(TrialRow.id),
        sa.func.count(TrialRow.lease_expires_at),
    )
    .outerjoin(TrialRow, TrialRow.study_id == StudyRow.id)
    .group_by(StudyRow.id, TrialRow.state)
)
"""One statement, so one snapshot on PostgreSQL: trial counts per study and state beside
each study's state, task, room, failed proposals and fallbacks."""


def database_gauges(session: Session) -> list[Metric]:
    families = {
        name: GaugeMetricFamily(name, help_, labels=list(labels))
        for name, (help_, labels) in DATABASE_GAUGES.items()
    }
    trials: dict[int, dict[str, int]] = {}
    failing: dict[int, int] = {}
    fallbacks: dict[int, int] = {}
    waiting = dict.fromkeys(catalogue().tasks, 0)
    leases = 0
    now = utcnow()
    for row in session.execute(_GAUGE_QUERY):
        study, study_state, task, max_trials, n_trials, failures, retry_at, fell, *rest = row
        state, count, leased = rest
        counts = trials.get(study)
        if counts is None:
            counts = trials[study] = dict.fromkeys(TrialState, 0)
            failing[study] = failures or 0
            fallbacks[study] = fell or 0
            # A study whose proposals fail waits for a worker only once its backoff is over.
            proposes = retry_at is None or retry_at <= now
            if study_state == "running" and task is not None and proposes:
                waiting[task] = waiting.get(task, 0) + max((max_trials or 0) - n_trials, 0)
        if state is None:
            continue  # a study without trials
        counts[state] = count
        if state == TrialState.running:
            leases += leased
        elif state == TrialState.queued and study_state == "running" and task is not None:
            waiting[task] = waiting.get(task, 0) + count
    for study, counts in sorted(trials.items()):
        for state, count in counts.items():
            families["activedesign_trials"].add_metric([str(study), state], count)
        families["activedesign_proposal_failures"].add_metric([str(study)], failing[study])
        families["activedesign_proposal_fallbacks"].add_metric([str(study)], fallbacks[study])
    families["activedesign_leases_active"].add_metric([], leases)
    for task, count in sorted(waiting.items()):
        families["activedesign_queue_depth"].add_metric([task], count)
    return list(families.values())


def route_template(scope: Scope) -> str:
    """The matched route's path template (never the raw path: labels stay bounded)."""
    route = scope.get("route")
    return getattr(route, "path_format", UNROUTED) if route is not None else UNROUTED


class HttpMetrics:
    """Pure ASGI middleware (outermost): times each HTTP request to its last byte and
    records it by method, route template and status."""

    def __init__(self, app: ASGIApp, metrics: Metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = perf_counter()
        status = 500  # unless an answer starts: an exception the server answers 500

        async def send_status(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_status)
        finally:
            method = scope["method"]
            self.metrics.observe(
                method if method in METHODS else "other",
                route_template(scope),
                status,
                perf_counter() - start,
            )


def install_metrics(app: FastAPI) -> None:
    """Count every request of ``app``; call it after the other middleware (it then runs
    first, so a request refused early is timed too)."""
    app.state.metrics = Metrics()
    app.add_middleware(HttpMetrics, metrics=app.state.metrics)
