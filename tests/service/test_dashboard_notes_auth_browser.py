"""Notes with auth on (issue 62) in a real headless Chromium against a real ``adserver``
with real tokens: the owner, signed in (a cookie and its CSRF token), writes the study's
note on its page; another user reads it and gets no way to edit it (the
server refuses them anyway: tests/service/test_notes_api.py, on both databases).
"""

from __future__ import annotations

from collections.abc import Callable

import httpx
import pytest

from adclient.testing.servers import SDK_HEADERS, ServerProcess, make_token
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import sign_in
from tests.service.test_dashboard_explore_browser import BOX, type_note

pytestmark = [
    pytest.mark.browser,
    pytest.mark.e2e,
    pytest.mark.xdist_group("browser"),
    # Who may write a note, on PostgreSQL: test_notes_api, on both.
    pytest.mark.parametrize("database", ["sqlite"]),
]


def test_with_auth_on_only_the_owner_may_edit_a_note_and_others_read_it(
    server_factory: Callable[..., ServerProcess], browser: Chromium
) -> None:
    secured = server_factory(AD_AUTH="true")
    owner = make_token(secured, "user", name="olga")
    other = make_token(secured, "user", name="pavel")
    headers = {**SDK_HEADERS, "Authorization": f"Bearer {owner}"}
    with httpx.Client(base_url=secured.url, headers=headers, timeout=30) as api:
        study = api.post("/api/v1/studies", json={"name": "olga's", "space": BOX}).json()["id"]
    scope = "[data-study-note]"
    text = f"document.querySelector('{scope} [data-note-text]').textContent"
    edit = f"document.querySelector('{scope} [data-note-edit]')"

    # The owner, signed in (a cookie and its CSRF token), writes it on the page.
    sign_in(browser, f"{secured.url}/#/studies/{study}", owner)
    assert browser.wait_for(f"{edit}.hidden === false && {edit}.textContent") == "Add a note"
    type_note(browser, scope, "olga's plan")
    assert browser.wait_for(f'{text} === "olga\'s plan" && {text}') == "olga's plan"
    assert "by olga" in browser.evaluate(
        f"document.querySelector('{scope} [data-note-meta]').textContent"
    )
    browser.evaluate("document.querySelector('[data-sign-out]').click()")

    # Another user's token reads it, with no way to edit it.
    sign_in(browser, f"{secured.url}/#/studies/{study}", other)
    assert browser.wait_for(f'{text} === "olga\'s plan" && {text}') == "olga's plan"
    assert browser.evaluate(f"{edit}.hidden") is True
    # The page's first load before each sign-in is refused (401), as on every page.
    assert [error for error in browser.errors if "HTTP 401" not in error] == []
