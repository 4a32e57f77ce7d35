"""The Debian packages the browser and PostgreSQL tests need, and what happens without them.

``make test`` runs this file before pytest, so ``apt-get`` runs once, before any test
process starts (parallel workers installing at once fight over apt's lock). It installs
only what is missing and says what it does:

    .venv/bin/python tests/system_packages.py

A test whose package is missing skips, loudly, on a developer's machine; where
``AD_REQUIRE_SYSTEM_TESTS=1`` (``.ci/run`` sets it) it fails, so CI cannot go green
without the browser and PostgreSQL tests. It runs before pytest, maybe without it:
besides the standard library it imports only the harness's PostgreSQL finder
(``adclient.testing.postgres``, installed with the project).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Callable, Mapping
from typing import NoReturn

from adclient.testing.postgres import postgres_bin_dir

REQUIRE = "AD_REQUIRE_SYSTEM_TESTS"
HOW_TO_INSTALL = "run `.venv/bin/python tests/system_packages.py` (what `make test` runs first)"


def chromium_executable() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


PACKAGES: dict[str, Callable[[], object]] = {
    "chromium": chromium_executable,
    "postgresql": postgres_bin_dir,
}
"""Each Debian package, and how to find what the tests run from it (None: missing)."""


def required(environ: Mapping[str, str] = os.environ) -> bool:
    """Whether a missing package fails the tests that need it instead of skipping them."""
    return environ.get(REQUIRE, "").strip().lower() not in ("", "0", "false", "no")


def unavailable(tests: str, why: str, environ: Mapping[str, str] = os.environ) -> NoReturn:
    """Skip ``tests`` (e.g. "BROWSER") because ``why``, or fail them where required."""
    import pytest  # not at the top: the installer runs before pytest, maybe without it

    if required(environ):
        message = f"{tests} TESTS CANNOT RUN ({REQUIRE} is set): {why}; {HOW_TO_INSTALL}"
        pytest.fail(message, pytrace=False)
    pytest.skip(f"{tests} TESTS SKIPPED: {why}; {HOW_TO_INSTALL}")


class CannotInstall(RuntimeError):
    pass


def missing() -> list[str]:
    return [package for package, find in PACKAGES.items() if find() is None]


def install(packages: list[str]) -> None:
    """``apt-get update`` then ``apt-get install``, with ``sudo -n`` unless root."""
    apt_get = shutil.which("apt-get")
    if apt_get is None:
        raise CannotInstall("apt-get is not available")
    sudo = []
    if os.geteuid() != 0:
        if shutil.which("sudo") is None:
            raise CannotInstall("not root, and sudo is not available")
        sudo = ["sudo", "-n"]
    # through env: sudo drops the caller's environment
    apt = [*sudo, "env", "DEBIAN_FRONTEND=noninteractive", apt_get]
    for command in (
        [*apt, "update", "-q"],
        [*apt, "install", "-y", "-q", "--no-install-recommends", *packages],
    ):
        print("+", " ".join(command), flush=True)
        if subprocess.run(command).returncode != 0:
            raise CannotInstall(f"`{' '.join(command)}` failed")


def main(environ: Mapping[str, str] = os.environ) -> int:
    """Install what is missing; 1 when that fails, except that a machine without apt-get
    goes on (its tests skip, loudly) unless the tests are required."""
    needed = missing()
    if not needed:
        print(f"system packages: {', '.join(PACKAGES)} already installed")
        return 0
    print(f"system packages: installing {', '.join(needed)} (browser and PostgreSQL tests)")
    try:
        install(needed)
    except CannotInstall as error:
        message = f"cannot install {', '.join(needed)}: {error}"
        if shutil.which("apt-get") is None and not required(environ):
            print(f"system packages: {message}; THEIR TESTS WILL BE SKIPPED", file=sys.stderr)
            return 0
        print(
            f"system packages: {message}. Install Debian's {' '.join(needed)} as root, "
            "or run `make test-fast` (no browser or PostgreSQL tests).",
            file=sys.stderr,
        )
        return 1
    if still := missing():
        print(f"system packages: apt-get ran but {', '.join(still)} not found", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
