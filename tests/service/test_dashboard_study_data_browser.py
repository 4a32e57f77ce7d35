"""Free-text names, user attributes and deleting a study, in a real headless Chromium
against a real ``adserver`` (issue 16): names and attributes are shown as text, never
markup; the delete button is there for those who may, asks first, and says why a study
with leased trials needs the leases cancelled."""

from __future__ import annotations

import json
from collections.abc import Callable

import httpx
import pytest

from adclient.testing.servers import SDK_HEADERS, ServerProcess, make_token
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import sign_in as dashboard_sign_in

pytestmark = [
    pytest.mark.browser,
    pytest.mark.e2e,
    pytest.mark.xdist_group("browser"),
    # PostgreSQL's names, attributes, deletes and owners: test_study_data_e2e, on both.
    pytest.mark.parametrize("database", ["sqlite"]),
]

HOSTILE = "<img src=x onerror=alert(1)>"
NAMES = ["Roboter-Entwurf 設計 v2", "stand up, long budget", "[bold]x[/bold]", HOSTILE]
MANAGED = {
    "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
    "proposer": {"name": "random"},
    "task": {"name": "noop", "external": True},
    "max_trials": 10,
}
READY = "document.querySelector('.study')?.dataset.ready === 'true'"
INJECTED = "document.querySelectorAll('img[src=\"x\"], b').length"


def text(browser: Chromium, selector: str) -> str:
    return str(browser.evaluate(f"document.querySelector({json.dumps(selector)}).textContent"))


def test_names_and_attributes_are_text_and_a_leased_study_is_deleted_with_force(
    live_server: ServerProcess, browser: Chromium
) -> None:
    with httpx.Client(base_url=live_server.url, headers=SDK_HEADERS, timeout=30) as http:
        ids = {  # the hostile name first: the oldest study is leased from first
            name: http.post("/api/v1/studies", json={**MANAGED, "name": name}).json()["id"]
            for name in [HOSTILE, *NAMES[:3]]
        }
        study = ids[HOSTILE]
        attrs = {"note": HOSTILE, "budget": {"steps": 1000}}
        http.patch(f"/api/v1/studies/{study}", json={"user_attrs": attrs}).raise_for_status()
        job = http.post("/api/v1/jobs/lease", json={"worker_id": "w"}).json()
        assert job["study_id"] == study
        trial_attrs = {"seed": 7, "label": "[bold]x[/bold] <b>y</b>"}
        patched = http.patch(
            f"/api/v1/trials/{job['trial_id']}", json={"worker_id": "w", "user_attrs": trial_attrs}
        )
        patched.raise_for_status()

    browser.navigate(f"{live_server.url}/")
    shown = browser.wait_for(
        "[...document.querySelectorAll('table.studies tbody tr')]"
        ".map(row => row.cells[0].querySelector('a').textContent)"
    )
    assert sorted(shown) == sorted(NAMES)
    assert browser.evaluate(INJECTED) == 0

    browser.navigate(f"{live_server.url}/#/studies/{study}")
    browser.wait_for(READY)
    assert text(browser, "[data-name]") == HOSTILE
    assert browser.evaluate("document.title") == f"{HOSTILE} · activedesign"
    assert text(browser, "[data-crumbs] a") == HOSTILE
    assert text(browser, "[data-attrs]") == f'note: {HOSTILE} · budget: {{"steps":1000}}'
    browser.evaluate(f"document.querySelector('[data-trial-id=\"{job['trial_id']}\"]').click()")
    rows = browser.wait_for(
        "[...document.querySelectorAll('[data-trial-dialog] [data-user-attrs] tr')]"
        ".map(row => [row.cells[0].textContent, row.cells[1].textContent])"
    )
    assert rows == [["seed", "7"], ["label", "[bold]x[/bold] <b>y</b>"]]
    assert browser.evaluate(INJECTED) == 0
    browser.evaluate("document.querySelector('[data-trial-dialog] [data-close]').click()")

    # Delete asks first; the leased trial makes the server refuse, and the dialog says so.
    assert browser.evaluate("document.querySelector('[data-delete]').hidden") is False
    browser.evaluate("document.querySelector('[data-delete]').click()")
    assert browser.evaluate("document.querySelector('[data-delete-dialog]').open") is True
    question = text(browser, "[data-delete-question]")
    assert HOSTILE in question and "1 trials" in question
    browser.evaluate("document.querySelector('[data-delete-cancel]').click()")
    assert browser.wait_for("!document.querySelector('[data-delete-dialog]').open")
    with httpx.Client(base_url=live_server.url, timeout=30) as http:
        assert http.get(f"/api/v1/studies/{study}").status_code == 200

        browser.evaluate("document.querySelector('[data-delete]').click()")
        browser.evaluate("document.querySelector('[data-delete-confirm]').click()")
        error = browser.wait_for(
            "!document.querySelector('[data-delete-error]').hidden"
            " && document.querySelector('[data-delete-error]').textContent"
        )
        assert "leased by worker(s) 'w'" in error
        assert text(browser, "[data-delete-confirm]") == "Delete and cancel the leases"
        assert http.get(f"/api/v1/studies/{study}").status_code == 200

        browser.evaluate("document.querySelector('[data-delete-confirm]').click()")
        browser.wait_for("location.hash === '#/'")
        assert http.get(f"/api/v1/studies/{study}").status_code == 404
    left = browser.wait_for(
        "(() => { const rows = [...document.querySelectorAll('table.studies tbody tr')];"
        " return rows.length === 3 && rows.map(row => row.cells[0].querySelector('a')"
        ".textContent); })()"
    )
    assert sorted(left) == sorted(NAMES[:3])
    assert browser.evaluate(INJECTED) == 0


def test_only_those_who_may_see_delete_and_a_signed_in_owner_deletes(
    server_factory: Callable[..., ServerProcess], browser: Chromium
) -> None:
    server = server_factory(AD_AUTH="true")
    owner, reader = make_token(server, "user", name="olga"), make_token(server, "reader")
    headers = {**SDK_HEADERS, "Authorization": f"Bearer {owner}"}
    with httpx.Client(base_url=server.url, headers=headers, timeout=30) as http:
        study = http.post("/api/v1/studies", json={**MANAGED, "name": "olga's"}).json()["id"]

    def sign_in(token: str) -> None:
        dashboard_sign_in(browser, f"{server.url}/#/studies/{study}", token)

    sign_in(reader)
    assert browser.evaluate("document.querySelector('[data-delete]').hidden") is True
    browser.evaluate("document.querySelector('[data-sign-out]').click()")

    sign_in(owner)
    assert browser.evaluate("document.querySelector('[data-delete]').hidden") is False
    browser.evaluate("document.querySelector('[data-delete]').click()")
    browser.evaluate("document.querySelector('[data-delete-confirm]').click()")
    browser.wait_for("location.hash === '#/'")
    with httpx.Client(base_url=server.url, headers=headers, timeout=30) as http:
        assert http.get(f"/api/v1/studies/{study}").status_code == 404
