"""The API docs pages in a real headless Chromium: Swagger UI and ReDoc render from the
server's own files under its Content-Security-Policy, asking nothing of another origin."""

from __future__ import annotations

import pytest

from adclient.testing.servers import ServerProcess
from tests.service.chromium import Chromium

pytestmark = [pytest.mark.browser, pytest.mark.e2e, pytest.mark.xdist_group("browser")]


@pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True)  # one for both pages
@pytest.mark.parametrize(
    ("page", "rendered"),
    [
        ("/docs", "document.querySelector('.swagger-ui .opblock-summary-path')?.textContent"),
        ("/redoc", "document.querySelector('.api-content h2')?.textContent"),
    ],
)
def test_docs_render_from_the_servers_own_files(
    shared_server: ServerProcess, browser: Chromium, page: str, rendered: str
) -> None:
    browser.navigate(shared_server.url + page)
    assert browser.wait_for(rendered, timeout=60)
    assert "activedesign" in browser.evaluate("document.body.innerText")
    fetched = [url for url in browser.requested if not url.startswith("data:")]
    elsewhere = [url for url in fetched if not url.startswith(shared_server.url)]
    assert elsewhere == []
    assert browser.errors == []
