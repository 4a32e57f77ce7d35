"""``adclient``: the command line of the SDK.

Every command talks to the server named by ``--server`` (env ``AD_SERVER_URL``) with
the token of ``--token`` (env ``AD_TOKEN``); an https server with a private or
self-signed certificate needs ``--ca-bundle`` (env ``AD_CA_BUNDLE``). Listings are
rich tables, or JSON with ``--json``. Errors end with one line on stderr and exit
status 1 (2 for bad usage), never a traceback.

The app, its options and what the commands share are in ``common``; the commands in
``studies`` (submit, studies, status, stop, note), ``workers``, ``trials`` (trials, best, pareto,
ask, tell, enqueue), ``data`` (import, export, delete), ``files`` (a trial's files, which
``best --save`` writes too) and ``replay`` (a trial's episode as a GIF); what ``submit``
reads in ``study_file``, and the closest valid name for an unknown field in ``suggest``.
"""

from __future__ import annotations

from importlib import import_module

from adclient.cli.common import app

__all__ = ["app", "main"]

# A command module registers its commands on ``app`` when imported, and ``adclient
# --help`` lists them in that order (which a sorted ``from ... import`` would not keep).
for _module in ("studies", "workers", "trials", "files", "replay", "data"):
    import_module(f"{__name__}.{_module}")


def main() -> None:
    """Console-script entry point."""
    app()
