"""The interactive API docs: Swagger UI at ``/docs``, ReDoc at ``/redoc``.

FastAPI's own pages load both from a CDN, unchecked, on the origin that holds the
dashboard's session, and start them with an inline script, which the server's
Content-Security-Policy refuses. These pages load the copies in ``static/vendor`` and
start them from a script file there.
"""

from __future__ import annotations

from html import escape

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse

router = APIRouter(include_in_schema=False)

VENDOR = "/vendor"
"""Where the dashboard's static mount serves ``static/vendor``."""


def _page(request: Request, head: str, body: str) -> HTMLResponse:
    title = escape(f"{request.app.title} API")
    return HTMLResponse(
        "<!doctype html>\n"
        f'<html lang="en"><head><meta charset="utf-8"><title>{title}</title>'
        f'<meta name="viewport" content="width=device-width, initial-scale=1">{head}</head>'
        f"<body>{body}</body></html>\n"
    )


@router.get("/docs")
def swagger_ui(request: Request) -> HTMLResponse:
    openapi = escape(request.app.openapi_url or "")
    return _page(
        request,
        f'<link rel="icon" href="{VENDOR}/favicon-32x32.png">'
        f'<link rel="stylesheet" href="{VENDOR}/swagger-ui.css">',
        f'<div id="swagger-ui" data-openapi="{openapi}"></div>'
        f'<script src="{VENDOR}/swagger-ui-bundle.js"></script>'
        f'<script src="{VENDOR}/swagger-init.js"></script>',
    )


@router.get("/redoc")
def redoc(request: Request) -> HTMLResponse:
    openapi = escape(request.app.openapi_url or "")
    return _page(
        request,
        f'<link rel="icon" href="{VENDOR}/favicon-32x32.png">',
        f'<div id="redoc" data-openapi="{openapi}"></div>'
        f'<script src="{VENDOR}/redoc.standalone.js"></script>'
        f'<script src="{VENDOR}/redoc-init.js"></script>',
    )
