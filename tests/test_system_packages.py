"""When chromium or postgresql is missing: skip on a developer's machine, fail in CI."""

from __future__ import annotations

import pytest

from tests import system_packages
from tests.system_packages import REQUIRE, main, required, unavailable


@pytest.mark.parametrize(
    ("environ", "expected"),
    [
        ({}, False),
        ({REQUIRE: ""}, False),
        ({REQUIRE: "0"}, False),
        ({REQUIRE: "false"}, False),
        ({REQUIRE: "1"}, True),
        ({REQUIRE: "yes"}, True),
        ({"OTHER": "1"}, False),
    ],
)
def test_required_only_when_asked(environ: dict[str, str], expected: bool) -> None:
    assert required(environ) is expected


def test_missing_package_skips_loudly_on_a_developer_machine() -> None:
    with pytest.raises(pytest.skip.Exception, match="BROWSER TESTS SKIPPED: no chromium"):
        unavailable("BROWSER", "no chromium", environ={})


def test_missing_package_fails_where_required() -> None:
    with pytest.raises(pytest.fail.Exception, match="POSTGRESQL TESTS CANNOT RUN") as failed:
        unavailable("POSTGRESQL", "no initdb", environ={REQUIRE: "1"})
    assert "tests/system_packages.py" in str(failed.value)


@pytest.fixture
def nothing_installed_no_apt(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every package missing and no apt-get: the installer cannot install."""
    monkeypatch.setattr(system_packages, "PACKAGES", {"chromium": lambda: None})
    monkeypatch.setattr(system_packages.shutil, "which", lambda _name: None)


@pytest.mark.usefixtures("nothing_installed_no_apt")
def test_installer_without_apt_goes_on_unless_required(capsys: pytest.CaptureFixture) -> None:
    assert main(environ={}) == 0
    assert "WILL BE SKIPPED" in capsys.readouterr().err
    assert main(environ={REQUIRE: "1"}) == 1
    assert "cannot install chromium: apt-get is not available" in capsys.readouterr().err


def test_installer_does_nothing_when_all_is_there(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    monkeypatch.setattr(system_packages, "PACKAGES", {"chromium": lambda: "/usr/bin/chromium"})
    monkeypatch.setattr(system_packages, "install", lambda _packages: pytest.fail("installed"))
    assert main(environ={REQUIRE: "1"}) == 0
    assert "already installed" in capsys.readouterr().out


def test_installer_fails_when_apt_get_fails(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    monkeypatch.setattr(system_packages, "PACKAGES", {"chromium": lambda: None})
    monkeypatch.setattr(system_packages.shutil, "which", lambda name: f"/usr/bin/{name}")
    monkeypatch.setattr(
        system_packages.subprocess,
        "run",
        lambda command: system_packages.subprocess.CompletedProcess(command, 100),
    )
    assert main(environ={}) == 1
    assert "apt-get update -q` failed" in capsys.readouterr().err
