"""Repository: every read and write of the service's rows, one module per aggregate.

Functions take an open session (from ``Database.read``/``Database.write``, the one
place that commits) and keyword-only arguments; they raise domain errors and
return ORM rows, which ``adservice.convert`` turns into API schemas.

Callers import the module they use (``from adservice.repository import trials as
trial_repo``); this package re-exports nothing. Each module imports only modules listed
above it, so there is no import circle:

- ``_shared``: what several of them use (row locks, worker upkeep, hot-path statements).
- ``transfer``: which evaluated design a job's controller starts from.
- ``studies``: create, read, count, stop a study; who manages it; its proposer history.
- ``trials``: new trials (asked, enqueued, added) and reading them (the ask hot path).
- ``leases``: leases and workers: lease, heartbeat, release, expiry; the workers seen.
- ``tell``: finishing a trial (the tell hot path).
- ``urdfs``: a template study's trial's URDF, expanded once and stored.
- ``artifacts``: a running trial's uploaded files and their quota.
- ``reports``: intermediate reports and learning curves.
- ``promotion``: ASHA pausing and promotion.
- ``edits``: deleting a study; user attributes of studies and trials.
- ``tokens``: API tokens and the dashboard's sign-in sessions.
"""
