"""The largest id a request may name, for the SDK's schemas and the service's routes alike
(a module of its own: the schemas and :mod:`adclient.pruning` both import it)."""

MAX_ID = 2**31 - 1
"""Ids and trial numbers are INTEGER columns, 32-bit on PostgreSQL: anything larger is a
422, not an overflow."""
