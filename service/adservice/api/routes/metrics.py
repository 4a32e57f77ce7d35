"""Prometheus' scrape target: text exposition, for readers when auth is on."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response
from prometheus_client import CONTENT_TYPE_LATEST

from adservice.api.deps import ReaderDep, SessionDep
from adservice.metrics import Metrics

router = APIRouter(tags=["metrics"])


@router.get(
    "/metrics",
    response_class=Response,
    responses={200: {"description": "Prometheus text format", "content": {"text/plain": {}}}},
)
def metrics(request: Request, session: SessionDep, _: ReaderDep) -> Response:
    app_metrics: Metrics = request.app.state.metrics
    state = request.app.state
    pools = {
        "creations": state.creations.counts(),
        "expansions": state.proposing.expansions.counts(),
    }
    return Response(app_metrics.render(session, pools), media_type=CONTENT_TYPE_LATEST)
