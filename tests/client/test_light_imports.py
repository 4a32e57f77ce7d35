"""The SDK stays light: its client and CLI never pull in the server's or worker's stack."""

from __future__ import annotations

import subprocess
import sys

HEAVY = (
    "fastapi",
    "starlette",
    "sqlalchemy",
    "torch",
    "botorch",
    "pybullet",
    "adservice",
    "adworker",
)


def test_client_and_cli_import_without_heavy_packages() -> None:
    code = (
        "import sys, adclient, adclient.client, adclient.cli\n"
        f"heavy = [m for m in sys.modules if m.split('.')[0] in {HEAVY!r}]\n"
        "print(','.join(sorted(heavy)))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == ""
