"""What a server's ``GET /metrics`` says, and what its database says: a test checks that
they agree, and the load benchmark checks it again after thousands of trials."""

from __future__ import annotations

import httpx
import sqlalchemy as sa
from prometheus_client.parser import text_string_to_metric_families

Samples = dict[tuple[str, tuple[tuple[str, str], ...]], float]
"""Every sample of a scrape: its value by (name, sorted labels)."""


def scrape(url: str, token: str | None = None) -> Samples:
    """Every sample of one scrape, by name and sorted labels."""
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    response = httpx.get(f"{url}/metrics", headers=headers, timeout=30, verify=False)
    assert response.status_code == 200, response.text
    assert response.headers["content-type"].startswith("text/plain")
    return {
        (sample.name, tuple(sorted(sample.labels.items()))): sample.value
        for family in text_string_to_metric_families(response.text)
        for sample in family.samples
    }


def in_database(url: str) -> tuple[dict[tuple[int, str], int], int]:
    """Trials by (study, state) and held leases, counted straight from the tables."""
    engine = sa.create_engine(url)
    try:
        with engine.connect() as connection:
            counts = {
                (study, state): count
                for study, state, count in connection.execute(
                    sa.text("SELECT study_id, state, count(*) FROM trials GROUP BY study_id, state")
                )
            }
            leases = connection.execute(
                sa.text(
                    "SELECT count(*) FROM trials "
                    "WHERE state = 'running' AND lease_expires_at IS NOT NULL"
                )
            ).scalar_one()
    finally:
        engine.dispose()
    return counts, leases


def trials_reported(samples: Samples) -> dict[tuple[int, str], float]:
    """The ``activedesign_trials`` gauge by (study, state), its zero series left out: what
    :func:`in_database` counts."""
    return {
        (int(dict(labels)["study"]), dict(labels)["state"]): value
        for (name, labels), value in samples.items()
        if name == "activedesign_trials" and value
    }
