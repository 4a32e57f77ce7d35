"""Cross-site requests in a real Chromium against a real adserver, auth off and on (issue
29): a page on another loopback port (another origin, the same site, so a SameSite
cookie still travels) submits a form and sends ``no-cors`` POSTs and a DELETE to the
API; nothing changes. ``curl -X DELETE`` with no body, as any REST client sends it,
deletes."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable

import httpx
import pytest

from adclient.testing.servers import ServerProcess, make_token
from tests.service.chromium import Chromium
from tests.service.sites import LoopbackSite

pytestmark = [pytest.mark.browser, pytest.mark.e2e, pytest.mark.xdist_group("browser")]

ASKED = {
    "name": "target",
    "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
    "proposer": {"name": "random"},
}
ATTACK = """<!doctype html><html><body>
<iframe name="sink"></iframe>
<form method="post" enctype="text/plain" target="sink" action="{api}/stop">
  <input name='{{"count": 1, "x"' value='1}}'>
</form>
<script>
window.attack = async () => {{
  document.forms[0].submit();
  const sent = [];
  for (const [path, type] of [["/ask", "text/plain"], ["/stop", ""],
                              ["/ask", "application/x-www-form-urlencoded"]]) {{
    const headers = type ? {{"Content-Type": type}} : {{}};
    await fetch("{api}" + path, {{method: "POST", mode: "no-cors", credentials: "include",
                                 headers, body: '{{"count": 1}}'}});
    sent.push(path);
  }}
  try {{
    await fetch("{api}", {{method: "DELETE", credentials: "include"}});
    sent.push("DELETE answered");
  }} catch (error) {{
    sent.push("DELETE refused by the browser");
  }}
  return sent;
}};
</script></body></html>"""


# Refused before storage: test_ownership_e2e's cross-site and cookie session tests, on both.
@pytest.mark.parametrize("database", ["sqlite"])
@pytest.mark.parametrize("auth", [False, True], ids=["auth-off", "auth-on"])
def test_a_page_of_another_origin_changes_nothing(
    server_factory: Callable[..., ServerProcess], browser: Chromium, auth: bool
) -> None:
    server = server_factory(**({"AD_AUTH": "true"} if auth else {}))
    headers = {"X-Activedesign-Client": "test"}
    token = make_token(server, "admin") if auth else ""
    if auth:
        headers["Authorization"] = f"Bearer {token}"
    with httpx.Client(base_url=server.url, timeout=30, headers=headers) as http:
        study = http.post("/api/v1/studies", json=ASKED).json()
        api = f"{server.url}/api/v1/studies/{study['id']}"
        if auth:  # the visitor is signed in: the session cookie goes with every request
            browser.navigate(f"{server.url}/")
            signed = browser.evaluate(
                "fetch('/api/v1/session', {method: 'POST', headers: {'Content-Type': "
                f"'application/json'}}, body: JSON.stringify({{token: {json.dumps(token)}}})}})"
                ".then(r => r.status)"
            )
            assert signed in (200, 201), signed
        site = LoopbackSite({"/": ATTACK.format(api=api)})  # another web site
        try:
            browser.navigate(site.url)
            browser.wait_for("typeof window.attack === 'function'")
            sent = browser.evaluate("window.attack()")
            browser.wait_for("document.querySelector('iframe').contentWindow !== null")
        finally:
            site.close()
        assert sent == ["/ask", "/stop", "/ask", "DELETE refused by the browser"]
        after = http.get(f"/api/v1/studies/{study['id']}")
        assert after.status_code == 200  # not deleted
        assert after.json()["state"] == "running" and after.json()["n_trials"] == 0
        # The same page's own request to its own server, with the header a client sends,
        # does change it: the requests above reached a server that would have acted.
        stopped = http.post(f"/api/v1/studies/{study['id']}/stop")
        assert stopped.status_code == 200 and stopped.json()["state"] == "stopped"


# A request without a body, not storage: test_study_data_e2e deletes on both databases.
@pytest.mark.parametrize("database", ["sqlite"])
@pytest.mark.parametrize("auth", [False, True], ids=["auth-off", "auth-on"])
def test_curl_deletes_a_study_with_a_plain_delete(
    server_factory: Callable[..., ServerProcess], auth: bool
) -> None:
    server = server_factory(**({"AD_AUTH": "true"} if auth else {}))
    token = make_token(server, "admin") if auth else ""
    bearer = {"Authorization": f"Bearer {token}"} if auth else {}
    with httpx.Client(base_url=server.url, timeout=30, headers=bearer) as http:
        sid = http.post("/api/v1/studies", json=ASKED).json()["id"]
        url = f"{server.url}/api/v1/studies/{sid}"

        def curl(*extra: str) -> str:
            return subprocess.run(
                [
                    "curl",
                    "-s",
                    "-o",
                    "/dev/null",
                    "-w",
                    "%{http_code}",
                    "-X",
                    "DELETE",
                    *extra,
                    url,
                ],
                capture_output=True,
                text=True,
                check=True,
            ).stdout

        if auth:
            assert curl() == "401"  # a plain DELETE still meets authentication
            assert http.get(f"/api/v1/studies/{sid}").status_code == 200
        assert curl(*(["-H", f"Authorization: Bearer {token}"] if auth else [])) == "204"
        assert http.get(f"/api/v1/studies/{sid}").status_code == 404
