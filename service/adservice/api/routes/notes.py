"""Notes on a study and on a trial (``GET``/``PUT``): readers read them, the study's
owner or an admin writes them; the text is bounded (``MAX_NOTE_CHARS``)."""

from __future__ import annotations

from fastapi import APIRouter

from adclient.schemas import Note, NoteUpdate
from adservice.api.deps import DatabaseDep, ReaderDep, SessionDep, StudyId, TrialId, UserDep
from adservice.services import notes

router = APIRouter(prefix="/api/v1", tags=["notes"])


@router.get("/studies/{study_id}/note")
def get_study_note(study_id: StudyId, session: SessionDep, _: ReaderDep) -> Note:
    """The study's note (empty text where none was written)."""
    return notes.study_note(session, study_id=study_id)


@router.put("/studies/{study_id}/note")
def put_study_note(study_id: StudyId, body: NoteUpdate, db: DatabaseDep, caller: UserDep) -> Note:
    """Replace the study's note (empty text removes it): its owner or an admin."""
    return notes.write_study_note(db, study_id=study_id, text=body.text, caller=caller)


@router.get("/trials/{trial_id}/note")
def get_trial_note(trial_id: TrialId, session: SessionDep, _: ReaderDep) -> Note:
    """The trial's note (empty text where none was written)."""
    return notes.trial_note(session, trial_id=trial_id)


@router.put("/trials/{trial_id}/note")
def put_trial_note(trial_id: TrialId, body: NoteUpdate, db: DatabaseDep, caller: UserDep) -> Note:
    """Replace the trial's note (empty text removes it): its study's owner or an admin."""
    return notes.write_trial_note(db, trial_id=trial_id, text=body.text, caller=caller)
