"""Repository: the notes of a study and of its trials (``NoteRow``).

The same conventions as every module of :mod:`adservice.repository`: an open session,
keyword-only arguments, domain errors. A write locks the study's row first, so two
writers of one note never both insert it."""

from __future__ import annotations

import sqlalchemy as sa
from sqlalchemy.orm import Session

from adservice.models import NoteRow, utcnow
from adservice.principals import Principal
from adservice.repository.studies import check_manager, get_study
from adservice.repository.trials import get_trial


def _subject(trial_id: int | None) -> sa.ColumnElement[bool]:
    return NoteRow.trial_id.is_(None) if trial_id is None else NoteRow.trial_id == trial_id


def note_row(session: Session, *, study_id: int, trial_id: int | None) -> NoteRow | None:
    """The note of the study (``trial_id`` None) or of its trial, None where none."""
    return session.scalar(
        sa.select(NoteRow).where(NoteRow.study_id == study_id, _subject(trial_id))
    )


def study_of_trial(session: Session, *, trial_id: int) -> int:
    """The study a trial belongs to (NotFoundError for no such trial)."""
    return get_trial(session, trial_id=trial_id).study_id


def check_study(session: Session, *, study_id: int) -> None:
    """NotFoundError for no such study."""
    get_study(session, study_id=study_id)


def set_note(
    session: Session, *, study_id: int, trial_id: int | None, text: str, caller: Principal
) -> NoteRow | None:
    """Write the note (empty text removes it): the study's owner or an admin only."""
    study = get_study(session, study_id=study_id, for_update=True)
    check_manager(study, caller)
    row = note_row(session, study_id=study_id, trial_id=trial_id)
    if not text:
        if row is not None:
            session.delete(row)
        return None
    if row is None:
        row = NoteRow(study_id=study_id, trial_id=trial_id, text=text)
        session.add(row)
    row.text = text
    row.updated_at = utcnow()
    row.updated_by = caller.name or None
    session.flush()
    return row
