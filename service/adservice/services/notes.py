"""Notes on a study and on a trial: read by the study's readers, written by its owner
(or an admin). The routes call one function here each; rows stay in the service."""

from __future__ import annotations

from sqlalchemy.orm import Session

from adclient.schemas import Note
from adservice.db import Database
from adservice.models import NoteRow
from adservice.principals import Principal
from adservice.repository import notes as note_repo


def _schema(row: NoteRow | None, *, study_id: int, trial_id: int | None) -> Note:
    if row is None:
        return Note(study_id=study_id, trial_id=trial_id)
    return Note(
        study_id=row.study_id,
        trial_id=row.trial_id,
        text=row.text,
        updated_at=row.updated_at,
        updated_by=row.updated_by,
    )


def study_note(session: Session, *, study_id: int) -> Note:
    note_repo.check_study(session, study_id=study_id)
    row = note_repo.note_row(session, study_id=study_id, trial_id=None)
    return _schema(row, study_id=study_id, trial_id=None)


def trial_note(session: Session, *, trial_id: int) -> Note:
    study_id = note_repo.study_of_trial(session, trial_id=trial_id)
    row = note_repo.note_row(session, study_id=study_id, trial_id=trial_id)
    return _schema(row, study_id=study_id, trial_id=trial_id)


def write_study_note(db: Database, *, study_id: int, text: str, caller: Principal) -> Note:
    with db.write() as session:
        row = note_repo.set_note(
            session, study_id=study_id, trial_id=None, text=text, caller=caller
        )
        return _schema(row, study_id=study_id, trial_id=None)


def write_trial_note(db: Database, *, trial_id: int, text: str, caller: Principal) -> Note:
    with db.write() as session:
        study_id = note_repo.study_of_trial(session, trial_id=trial_id)
        row = note_repo.set_note(
            session, study_id=study_id, trial_id=trial_id, text=text, caller=caller
        )
        return _schema(row, study_id=study_id, trial_id=trial_id)
