"""The browser tests' Chromium leaves nothing in the machine's temporary folder."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest

from tests.service.chromium import Chromium

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
