"""Notes on a study and on a trial (issue 62) against a real ``adserver`` with auth on
and real tokens (``adserver token create``), on SQLite and PostgreSQL: the owner writes,
another user and a reader only read (403), the text is bounded (422 naming the bound),
kept as the exact text sent (markup included: the dashboard shows it as text), empty
text removes it, and a note goes with its study."""

from __future__ import annotations

import httpx
import pytest

from adclient.schemas import MAX_NOTE_CHARS
from adclient.testing.servers import ServerProcess, make_token
from adclient.testing.workers import run_adclient

pytestmark = [pytest.mark.e2e]

ASKED = {
    "name": "noted",
    "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
    "proposer": {"name": "random"},
}
HOSTILE = "<img src=x onerror=\"document.title='owned'\">\n<script>alert(1)</script> & more"


def client(server: ServerProcess, role: str, name: str = "") -> httpx.Client:
    return httpx.Client(
        base_url=server.url,
        headers={
            "Authorization": f"Bearer {make_token(server, role, name=name)}",
            "X-Activedesign-Client": "test",
        },
        timeout=30,
        verify=False,
    )


def test_only_the_owner_writes_notes_everyone_reads_them_bounded_and_as_sent(
    secured: ServerProcess,
) -> None:
    alice = client(secured, "user", "alice")
    bob = client(secured, "user", "bob")
    reader = client(secured, "reader", "rita")
    study = alice.post("/api/v1/studies", json=ASKED).raise_for_status().json()
    sid = study["id"]
    (trial,) = alice.post(f"/api/v1/studies/{sid}/ask", json={"count": 1}).json()["trials"]

    empty = reader.get(f"/api/v1/studies/{sid}/note").raise_for_status().json()
    assert empty == {
        "study_id": sid, "trial_id": None, "text": "", "updated_at": None, "updated_by": None
    }  # fmt: skip
    written = alice.put(f"/api/v1/studies/{sid}/note", json={"text": HOSTILE})
    assert written.status_code == 200, written.text
    assert written.json()["text"] == HOSTILE and written.json()["updated_by"] == "alice"
    trial_note = alice.put(f"/api/v1/trials/{trial['id']}/note", json={"text": "ran hot"})
    assert trial_note.json()["trial_id"] == trial["id"] and trial_note.json()["study_id"] == sid

    # Another user's token and a reader's: they read both notes, they change neither.
    for other in (bob, reader):
        assert other.get(f"/api/v1/studies/{sid}/note").json()["text"] == HOSTILE
        assert other.get(f"/api/v1/trials/{trial['id']}/note").json()["text"] == "ran hot"
        for path in (f"/api/v1/studies/{sid}/note", f"/api/v1/trials/{trial['id']}/note"):
            refused = other.put(path, json={"text": "mine now"})
            assert refused.status_code == 403, refused.text
    assert reader.get(f"/api/v1/studies/{sid}/note").json()["text"] == HOSTILE

    # Bounded: one character over is refused, naming the bound; the note is unchanged.
    long = alice.put(f"/api/v1/studies/{sid}/note", json={"text": "x" * (MAX_NOTE_CHARS + 1)})
    assert long.status_code == 422 and str(MAX_NOTE_CHARS) in long.text, long.text
    exact = alice.put(f"/api/v1/trials/{trial['id']}/note", json={"text": "y" * MAX_NOTE_CHARS})
    assert exact.status_code == 200
    assert alice.put(f"/api/v1/studies/{sid}/note", json={"text": "a\x00b"}).status_code == 422
    assert alice.get(f"/api/v1/studies/{sid}/note").json()["text"] == HOSTILE

    # Unknown ones are 404; empty text removes a note; the study's notes go with it.
    assert reader.get("/api/v1/trials/987654/note").status_code == 404
    assert alice.put("/api/v1/studies/987654/note", json={"text": "x"}).status_code == 404
    alice.put(f"/api/v1/studies/{sid}/note", json={"text": ""}).raise_for_status()
    assert alice.get(f"/api/v1/studies/{sid}/note").json()["updated_at"] is None
    assert alice.get(f"/api/v1/trials/{trial['id']}/note").json()["text"] == "y" * MAX_NOTE_CHARS
    alice.delete(f"/api/v1/studies/{sid}").raise_for_status()
    assert reader.get(f"/api/v1/trials/{trial['id']}/note").status_code == 404
    assert reader.get(f"/api/v1/studies/{sid}/note").status_code == 404


# The CLI reads what the API answers: on SQLite alone (the API test above runs on both).
@pytest.mark.parametrize("secured", ["sqlite"], indirect=True)
def test_adclient_note_reads_and_writes_a_study_and_a_trials_note(secured: ServerProcess) -> None:
    """``adclient note STUDY [--trial N] [TEXT]`` as a user runs it: the owner writes, the
    note prints as it was written (markup as text), another user is refused (exit 4)."""
    alice_token = make_token(secured, "user", name="carol")
    alice = httpx.Client(
        base_url=secured.url,
        headers={"Authorization": f"Bearer {alice_token}", "X-Activedesign-Client": "test"},
        timeout=30,
        verify=False,
    )
    sid = alice.post("/api/v1/studies", json=ASKED).raise_for_status().json()["id"]
    alice.post(f"/api/v1/studies/{sid}/ask", json={"count": 2}).raise_for_status()
    as_carol = ("--token", alice_token)

    empty = run_adclient(secured, *as_carol, "note", str(sid))
    assert empty.returncode == 0 and empty.stdout.strip() == f"study {sid} has no note"
    text = "[bold]two[/bold] lines\nhere"
    saved = run_adclient(secured, *as_carol, "note", str(sid), text)
    assert saved.returncode == 0, saved.stderr
    assert saved.stdout.strip() == f"note of study {sid} saved: {len(text)} characters"
    shown = run_adclient(secured, *as_carol, "note", str(sid))
    assert shown.stdout == "[bold]two[/bold] lines\nhere\n"
    run_adclient(secured, *as_carol, "note", str(sid), "--trial", "1", "the good one")
    trial = alice.get(f"/api/v1/studies/{sid}/trials", params={"numbers": "1"}).json()[0]
    assert alice.get(f"/api/v1/trials/{trial['id']}/note").json()["text"] == "the good one"
    assert run_adclient(secured, *as_carol, "note", str(sid), "--trial", "1").stdout == (
        "the good one\n"
    )
    missing = run_adclient(secured, *as_carol, "note", str(sid), "--trial", "7")
    assert missing.returncode == 1 and f"study {sid} has no trial 7" in missing.stderr

    other = ("--token", make_token(secured, "user", name="dave"))
    refused = run_adclient(secured, *other, "note", str(sid), "mine")
    assert refused.returncode == 4, refused.stderr  # forbidden: the README's exit codes
    assert "only its owner or an admin may change it" in refused.stderr
    assert run_adclient(secured, *other, "note", str(sid)).stdout.startswith("[bold]two")
