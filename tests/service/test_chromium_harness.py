"""The browser tests' Chromium: it leaves nothing in the machine's temporary folder; the
pages of one shared browser share no cookies, storage or cache; the page tests take in
turn is blank with nothing recorded at each take; a shared browser that died or hung is
replaced."""

from __future__ import annotations

import signal
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.service.chromium import BROKEN, Chromium, SharedChromium
from tests.service.sites import LoopbackSite

pytestmark = [pytest.mark.browser, pytest.mark.xdist_group("browser")]


def test_chromium_keeps_its_singleton_folder_in_its_profile(
    chromium_executable: str, tmp_path: Path
) -> None:
    """Stopped by a signal, Chromium leaves its org.chromium.Chromium.* folder where
    TMPDIR says (hundreds of them piled up in /tmp): a folder of the harness's own,
    removed at close."""
    profile = tmp_path / "profile"
    profile.mkdir()
    chromium = Chromium(chromium_executable, profile)
    try:
        assert chromium.evaluate("1 + 1") == 2
        assert list(chromium.temporary.glob("org.chromium.Chromium.*"))
    finally:
        chromium.close()
    assert chromium.process.returncode is not None
    assert not chromium.temporary.exists()


def test_a_browser_that_never_comes_up_leaves_no_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A Chromium that exits at once (here /bin/false) fails with its log, and its
    temporary folder is removed all the same."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    profile = tmp_path / "profile"
    profile.mkdir()
    with pytest.raises(RuntimeError, match="did not open its DevTools port"):
        Chromium("/bin/false", profile)
    assert not list(tmp_path.glob("adchromium-*"))


@pytest.fixture
def site() -> Iterator[LoopbackSite]:
    """A page at "/" (titled "site") and a cacheable ``/cached``."""
    served = LoopbackSite(
        {"/": "<!doctype html><title>site</title>", "/cached": "{}"}, cache_seconds=3600
    )
    yield served
    served.close()


@pytest.fixture
def shared(chromium_executable: str, tmp_path: Path) -> Iterator[SharedChromium]:
    """A shared browser of this test's own (one it may kill)."""
    chromium = SharedChromium(chromium_executable, tmp_path, answer_within=2.0)
    yield chromium
    chromium.close()


def visit(page: Chromium, site: LoopbackSite) -> dict[str, Any]:
    """What the page finds of the site's cookies and storage, having fetched /cached."""
    page.navigate(site.url)
    page.wait_for("document.title === 'site'")
    found: dict[str, Any] = page.evaluate(
        "fetch('/cached').then(() => ({cookie: document.cookie,"
        " stored: localStorage.getItem('kept'), session: sessionStorage.getItem('kept')}))"
    )
    page.evaluate(
        "document.cookie = 'kept=1; max-age=3600';"
        " localStorage.setItem('kept', '1'); sessionStorage.setItem('kept', '1')"
    )
    return found


def test_pages_of_one_browser_share_no_cookies_storage_or_cache(
    shared: SharedChromium, site: LoopbackSite
) -> None:
    """Each page (one per test) has a browser context of its own: what one page stored,
    or cached, a later page of the same browser, or one open beside it, does not see."""
    first = shared.page()
    assert visit(first, site) == {"cookie": "", "stored": None, "session": None}
    assert visit(first, site) == {"cookie": "kept=1", "stored": "1", "session": "1"}
    assert site.hits["/cached"] == 1  # the second fetch came from the page's cache
    beside = shared.page()
    assert visit(beside, site) == {"cookie": "", "stored": None, "session": None}
    assert site.hits["/cached"] == 2
    assert first.evaluate("document.visibilityState") == "visible"  # still drawn
    first.close()
    beside.close()
    later = shared.page()
    try:
        assert visit(later, site) == {"cookie": "", "stored": None, "session": None}
        assert site.hits["/cached"] == 3
        assert later.process is first.process and shared.started == 1  # one browser
    finally:
        later.close()


def test_the_shared_page_is_blank_with_nothing_recorded_at_each_take(
    shared: SharedChromium, site: LoopbackSite
) -> None:
    """The page tests take in turn (``shared_page``) is one page: each take finds it at
    about:blank, with the last test's errors and requests forgotten and what it stored
    or cached gone (cookies, local and session storage, the cache), as a new page's;
    once its browser was replaced, it is a page of the new one."""
    page = shared.shared_page()
    assert visit(page, site) == {"cookie": "", "stored": None, "session": None}
    assert visit(page, site) == {"cookie": "kept=1", "stored": "1", "session": "1"}
    assert site.hits["/cached"] == 1  # the second fetch came from the cache
    page.evaluate("setTimeout(() => { throw new Error('late'); }, 0)")
    page.wait_for("true")
    assert page.requested and page.errors
    again = shared.shared_page()
    assert again is page and shared.started == 1
    assert again.evaluate("location.href") == "about:blank"
    assert again.errors == [] and again.requested == []
    assert visit(again, site) == {"cookie": "", "stored": None, "session": None}
    assert site.hits["/cached"] == 2
    page.owner.process.kill()
    page.owner.process.wait()
    after = shared.shared_page()
    assert after is not page and shared.started == 2
    assert after.evaluate("location.href") == "about:blank"


@pytest.mark.parametrize("how", ["killed", "hung"])
def test_a_dead_or_hung_browser_is_replaced(shared: SharedChromium, how: str) -> None:
    """A shared browser that crashed (killed) or stopped answering (stopped by SIGSTOP)
    fails at most the test it happened in: the next page is in a new browser, and the
    old one leaves no process or folder."""
    page = shared.page()
    assert page.evaluate("1 + 1") == 2
    old = page.owner
    if how == "killed":
        old.process.kill()
        old.process.wait()
    else:
        old.process.send_signal(signal.SIGSTOP)
    with pytest.raises(BROKEN):
        page.send("Runtime.evaluate", timeout=2, expression="1 + 1")
    page.close()  # what the fixture does after the failed test: no error of its own
    after = shared.page()
    try:
        assert after.owner is not old and shared.started == 2
        assert after.evaluate("1 + 1") == 2
        assert old.process.returncode is not None
        assert not old.temporary.exists()
    finally:
        after.close()


def test_wait_for_polls_in_the_page_as_python_sees_values(
    browser: Chromium, site: LoopbackSite
) -> None:
    """``wait_for`` returns the first value Python finds truthy (a DOM node, an empty
    list or object is not), across a navigation that replaces the document it polls, and
    names a throwing expression's error when it times out."""
    browser.navigate(site.url)
    browser.wait_for("document.title === 'site'")
    browser.evaluate("setTimeout(() => { window.later = [1, {a: 2}]; }, 300)")
    assert browser.wait_for("window.later") == [1, {"a": 2}]
    for falsy in ("document.body", "[]", "({})", "0", "''", "null"):
        with pytest.raises(AssertionError, match=r"timed out after 0\.3s"):
            browser.wait_for(falsy, timeout=0.3)
    assert browser.wait_for("!!document.body") is True
    browser.evaluate("setTimeout(() => { location.href = '/cached'; }, 200)")
    ready = "location.pathname === '/cached' && document.readyState === 'complete'"
    assert browser.wait_for(ready) is True
    with pytest.raises(AssertionError, match="threw: TypeError"):
        browser.wait_for("document.querySelector('#none').textContent", timeout=0.3)
