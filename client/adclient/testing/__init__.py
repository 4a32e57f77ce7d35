"""The process harness the tests and the benchmarks share, as ``optuna.testing`` is
Optuna's: real ``adserver`` and ``adworker`` processes on free loopback ports
(:mod:`.servers`, :mod:`.workers`), a throwaway PostgreSQL cluster (:mod:`.postgres`),
a ``/metrics`` scrape and the tables it must agree with (:mod:`.metrics`), and the
workloads both measure or check: simulated workers under load (:mod:`.load`, scoring
with :mod:`.noop`), slow and oversized clients (:mod:`.attacks`), one study's heavy ask
beside another's leases (:mod:`.isolation`), and the design suite's synthetic objectives
(:mod:`.design_objectives`).

It starts the programs by command, as an operator does, and never imports
``adservice`` or ``adworker``; ``adclient`` itself never imports it, so the SDK stays
light. :mod:`.servers`, :mod:`.workers`, :mod:`.attacks`, :mod:`.isolation` and
:mod:`.noop` need only the SDK's own dependencies; :mod:`.postgres`, :mod:`.metrics`
and :mod:`.load` need the ``service`` extra (psycopg, prometheus-client, SQLAlchemy).
"""
