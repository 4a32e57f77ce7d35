"""A study whose proposals fail keeps its failure to itself.

Any exception from a study's proposal (a model fit, canonicalising a candidate, a bug,
memory) used to answer 500 to whoever asked: to a worker's lease too, so the oldest
study with a broken proposal failed every lease and no other study got a trial. Now it
is recorded on the study (its error, the failures in a row, and ``proposal_retry_at``,
before which the lease scheduler skips the study) and raised as
``ProposalFailedError``: a lease goes on to the next study, an owner's ask gets a 409
naming the failure. The proposal's own write transaction was rolled back, so nothing
of it is stored (no trial, no trial number, no attempt). The next proposal that
succeeds clears the record (``trial_repo.reserve_for_proposal``, in its write).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from adservice.db import Database
from adservice.errors import DomainError, ProposalFailedError, StudyConfigError
from adservice.models import StudyRow
from adservice.repository import studies as study_repo

log = logging.getLogger("adservice")

MAX_ERROR_CHARS = 2000
"""How much of an exception's text a study keeps (and an answer repeats)."""


@dataclass(frozen=True)
class Backoff:
    """How long leases skip a study after its proposals fail: ``seconds`` after the
    first failure, doubled with each failure in a row, at most ``max_seconds``; at the
    cap the study is still tried at that interval, since a failure may pass (memory)."""

    seconds: float = 5.0
    max_seconds: float = 600.0


def error_text(error: BaseException) -> str:
    """An exception as the study records it: its type and message, never a traceback."""
    message = str(error).strip()
    text = f"{type(error).__name__}: {message}" if message else type(error).__name__
    return text[:MAX_ERROR_CHARS]


@contextmanager
def failures_recorded(db: Database, backoff: Backoff, *, study_id: int) -> Iterator[None]:
    """Run a study's proposal: a failure of the study itself (stored settings that
    cannot be used, or any exception that is not a domain error) is recorded with its
    backoff; the request's own errors (forbidden, full, stopped, too large) are not."""
    try:
        yield
    except StudyConfigError as error:
        _store_failure(db, backoff, study_id=study_id, error=error.detail)
        raise
    except DomainError:
        raise
    except Exception as error:
        text = error_text(error)
        log.warning("study %d: proposal failed", study_id, exc_info=True)
        study = _store_failure(db, backoff, study_id=study_id, error=text)
        detail = f"study {study_id}'s proposal failed: {text}"
        if study is not None and study.proposal_retry_at is not None:
            detail += (
                f" ({study.proposal_failures} in a row; workers' leases skip the study until "
                f"{study.proposal_retry_at:%Y-%m-%d %H:%M:%S} UTC)"
            )
        raise ProposalFailedError(detail) from error


def _store_failure(db: Database, backoff: Backoff, *, study_id: int, error: str) -> StudyRow | None:
    """The failure written in its own short transaction; None when it could not be (the
    study was deleted meanwhile, the database is away): the caller still gets its error."""
    try:
        with db.write() as session:
            return study_repo.record_proposal_failure(
                session,
                study_id=study_id,
                error=error,
                backoff_seconds=backoff.seconds,
                max_backoff_seconds=backoff.max_seconds,
            )
    except Exception:
        log.warning("study %d: its proposal failure was not recorded", study_id, exc_info=True)
        return None
