"""Issue 62: a running study with no trial limit (the Optuna sampler's, which stays
running when ``optimize`` returns) does not read as done on the dashboard: its
progress bar is faded and its counts say "no trial limit", on the studies list and its
own page; a study with max_trials, or one stopped, shows its bar as before. A real
Optuna run against a real ``adserver`` (conftest's ``shared_server``), one Chromium."""

from __future__ import annotations

import httpx
import optuna
import pytest

from adclient import Client
from adclient.optuna import ServiceSampler
from adclient.testing.servers import ServerProcess
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import STUDY_PAGE_READY

pytestmark = [
    pytest.mark.browser,
    pytest.mark.e2e,
    pytest.mark.xdist_group("browser"),
    # the page reads the study's max_trials and state alone (no database-specific read)
    pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True),
]

ROW = (
    "[...document.querySelectorAll('table.studies tr')].filter(row => "
    "row.querySelector('a')?.getAttribute('href') === '#/studies/{id}').map(row => "
    "[row.querySelector('.progress').hasAttribute('data-open-ended'), "
    "row.querySelector('.progress-cell .meta').textContent])[0]"
)


@pytest.fixture(scope="module")
def server(shared_server: ServerProcess) -> ServerProcess:
    return shared_server


def test_a_running_study_with_no_trial_limit_does_not_read_as_done(
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    client = Client(server.url)
    sampler = ServiceSampler(client, study_name="open-ended", proposer="random")
    study = optuna.create_study(study_name="open-ended", sampler=sampler)
    study.optimize(lambda trial: trial.suggest_float("x", 0.0, 1.0), n_trials=3)
    service = sampler.service_study
    assert service is not None
    space = {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]}
    body = {"name": "limited", "space": space, "max_trials": 3}
    limited = http.post("/api/v1/studies", json=body).raise_for_status().json()["id"]

    browser.navigate(f"{server.url}/#/")
    browser.wait_for(ROW.format(id=limited))
    open_ended, counts = browser.evaluate(ROW.format(id=service.id))
    assert open_ended
    assert counts.endswith("3 complete · 0 running · 0 queued · 0 failed · no trial limit")
    open_ended, counts = browser.evaluate(ROW.format(id=limited))
    assert not open_ended and counts.endswith("of 3") and "no trial limit" not in counts

    browser.navigate(f"{server.url}/#/studies/{service.id}")
    browser.wait_for(STUDY_PAGE_READY)
    assert browser.evaluate("!!document.querySelector('[data-progress] [data-open-ended]')")
    assert (
        browser.evaluate("document.querySelector('[data-counts] .meta').textContent")
        == "3 asked, no trial limit"
    )

    service.stop()  # stopped: it has ended, and its bar is its last state
    browser.navigate(f"{server.url}/#/")
    browser.wait_for(ROW.format(id=service.id))
    browser.wait_for(f"!{ROW.format(id=service.id)}[0]")
    assert "no trial limit" not in browser.evaluate(ROW.format(id=service.id))[1]
    assert browser.errors == []
    client.close()
