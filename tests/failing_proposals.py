"""A study whose every proposal raises, for the tests of issue 36's isolation.

The poison: a design study's stored representation names one spec fewer than its space
has, as a server of another version could have stored it. The study reads, lists and
shows as before, and its proposer runs, but turning any candidate into a design raises
(``adclient.decode``: "the representation does not belong to this space"). It is written
into the database directly (no request can store it), before any server process has
read the study's configuration (each process reads it once)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import sqlalchemy as sa
import yaml

from adservice.models import StudyRow

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
ERROR = "ValueError: the representation does not belong to this space"
"""How the study's recorded ``proposal_error`` starts."""


def design_study(name: str, **fields: Any) -> dict[str, Any]:
    """diagonal-gesture's two-joint arm (a 4-dimensional design space), with ``fields``."""
    body = yaml.safe_load((EXAMPLES / "diagonal-gesture.yaml").read_text())
    body.pop("task")
    body.pop("max_trials")
    return {**body, "name": name, **fields}


def unfit_representation(database_url: str, study_id: int) -> dict[str, Any]:
    """Poison the study (see the module); returns its representation as it was."""
    representation = read_representation(database_url, study_id)
    unfit = {**representation, "spec_names": representation["spec_names"][:-1]}
    store_representation(database_url, study_id, unfit)
    return representation


def read_representation(database_url: str, study_id: int) -> dict[str, Any]:
    engine = sa.create_engine(database_url)
    try:
        with engine.connect() as connection:
            query = sa.select(StudyRow.representation).where(StudyRow.id == study_id)
            representation: dict[str, Any] = connection.execute(query).scalar_one()
    finally:
        engine.dispose()
    return representation


def store_representation(database_url: str, study_id: int, representation: dict[str, Any]) -> None:
    update_study(database_url, study_id, representation=representation)


def update_study(database_url: str, study_id: int, **values: Any) -> None:
    """Set columns of a study's row directly, as no request can."""
    engine = sa.create_engine(database_url)
    try:
        with engine.begin() as connection:
            connection.execute(sa.update(StudyRow).where(StudyRow.id == study_id).values(**values))
    finally:
        engine.dispose()
