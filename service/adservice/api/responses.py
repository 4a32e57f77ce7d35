"""Responses that skip FastAPI's second pass over a model the route already built."""

from __future__ import annotations

from fastapi import Response
from pydantic import BaseModel


def model_response(model: BaseModel, status_code: int = 200) -> Response:
    """``model`` as JSON, serialised once by pydantic. A route returning a Response is not
    validated again; declare ``response_model`` so the OpenAPI document keeps the schema."""
    return Response(model.model_dump_json(), status_code=status_code, media_type="application/json")
