"""Notes: free text a study's owner keeps on the study or on one of its trials, read by
anyone who may read the study (``GET``/``PUT /studies/{id}/note``,
``/trials/{id}/note``). Text, never markup: the dashboard shows it as text."""

from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, Field

from adclient.strict import StrictInput

MAX_NOTE_CHARS = 10_000
"""The most characters a note holds: a page of text, bounded like every input."""


class Note(BaseModel):
    """A study's or a trial's note; empty text (and no time) where none was written."""

    study_id: int
    trial_id: int | None = Field(default=None, description="null for the study's own note")
    text: str = ""
    updated_at: datetime | None = None
    updated_by: str | None = Field(
        default=None, description="the token name that wrote it last (null with auth off)"
    )


class NoteUpdate(StrictInput):
    """``PUT .../note``: the note's whole new text; empty text removes the note."""

    text: str = Field(
        max_length=MAX_NOTE_CHARS,
        pattern=r"^[^\x00]*$",
        description=f"at most {MAX_NOTE_CHARS} characters, no NUL",
    )
