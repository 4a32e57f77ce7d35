"""Hostile input against a real ``adserver``, on SQLite and on PostgreSQL: each request
is answered with a 4xx naming what is wrong, never a 500; no request costs more than a
bounded page; and nothing one caller stores can break a read for everyone else."""

from __future__ import annotations

import contextlib
import re
import socket
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import sqlalchemy as sa
import yaml
from sqlalchemy.orm import Session

from adclient import Client
from adclient.schemas import CUT_JSON, MAX_JSON_BYTES, MAX_JSON_DEPTH, MAX_TRIAL_PAGE
from adclient.testing.servers import ServerProcess
from adservice.models import StudyRow
from adservice.views import SERIES_CELLS, SERIES_PAGE

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("hostile-input")]
"""One xdist worker runs the module: the tests on ``shared_server`` share its two servers."""

BOX = {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]}
STUDY = {"name": "hostile", "space": BOX, "proposer": {"name": "random", "seed": 1}}
EXTERNAL = {"name": "mine", "external": True}


@pytest.fixture
def http(shared_server: ServerProcess) -> Iterator[httpx.Client]:
    """The module's server: a test looks at its own studies, or at what it added."""
    with httpx.Client(base_url=shared_server.url, timeout=60, verify=False) as client:
        yield client


@pytest.fixture
def own_http(live_server: ServerProcess) -> Iterator[httpx.Client]:
    """A server of the test's own, for a test that writes to its database."""
    with httpx.Client(base_url=live_server.url, timeout=60, verify=False) as client:
        yield client


def nested(levels: int) -> dict[str, Any]:
    """An object ``levels`` deep: {"a": {"a": ... {}}}."""
    value: dict[str, Any] = {}
    for _ in range(levels - 1):
        value = {"a": value}
    return value


def depth_of(value: Any) -> int:
    if isinstance(value, dict):
        return 1 + max((depth_of(item) for item in value.values()), default=0)
    return 0


def create(http: httpx.Client, **fields: Any) -> dict[str, Any]:
    response = http.post("/api/v1/studies", json=STUDY | fields)
    assert response.status_code == 201, response.text
    return dict(response.json())


def ask(http: httpx.Client, study_id: int, count: int) -> None:
    for start in range(0, count, 64):
        asked = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": min(64, count - start)})
        assert asked.status_code == 200, asked.text


def refused_study(http: httpx.Client, fields: dict[str, Any]) -> str:
    """The detail of a study creation refused with a 422, having checked it stored none."""
    before = http.get("/api/v1/studies").json()
    response = http.post("/api/v1/studies", json=STUDY | fields)
    assert response.status_code == 422, response.text
    assert http.get("/api/v1/studies").json() == before
    return str(response.json()["detail"])


# --- paging ---------------------------------------------------------------------------


def test_offsets_past_the_integer_columns_are_422_not_an_overflow(http: httpx.Client) -> None:
    study = create(http)
    url = f"/api/v1/studies/{study['id']}/trials"
    for offset in (2**31, 2**63, 2**64, 10**30):
        for name in ("offset", "after"):
            response = http.get(url, params={name: offset})
            assert response.status_code == 422, response.text
            assert name in response.json()["detail"]
    last = http.get(url, params={"offset": 2**31 - 1, "after": 2**31 - 1})
    assert last.status_code == 200 and last.json() == []


def test_trials_come_a_bounded_page_at_a_time(http: httpx.Client) -> None:
    study = create(http)
    total = MAX_TRIAL_PAGE + 88
    ask(http, study["id"], total)
    url = f"/api/v1/studies/{study['id']}/trials"
    first = http.get(url)
    assert len(first.json()) == MAX_TRIAL_PAGE
    assert first.headers["X-Total-Count"] == str(total)
    for limit in (MAX_TRIAL_PAGE + 1, 100_000):
        assert http.get(url, params={"limit": limit}).status_code == 422
    rest = http.get(url, params={"after": MAX_TRIAL_PAGE}).json()
    assert [trial["number"] for trial in rest] == list(range(MAX_TRIAL_PAGE, total))


@pytest.mark.parametrize(
    "path", ["/api/v1/studies/{id}/series", "/api/v1/dashboard/studies/{id}/series"]
)
def test_series_of_a_wide_study_ends_each_page_at_the_cell_budget(
    http: httpx.Client, path: str
) -> None:
    width, total = 256, 1100
    space = {
        "type": "box",
        "params": [{"name": f"p{i}", "low": 0, "high": 1} for i in range(width)],
    }
    study = create(http, space=space)
    ask(http, study["id"], total)
    url = path.format(id=study["id"])
    pages: list[list[int]] = []
    after: int | None = 0
    while after is not None:
        page = http.get(url, params={"after": after}).json()
        assert len(page["number"]) * width <= SERIES_CELLS + width
        assert all(len(column) == len(page["number"]) for column in page["params"].values())
        pages.append(page["number"])
        after = page["next"]
    assert len(pages) == -(-total * width // SERIES_CELLS)  # ceil: pages end on the budget
    assert [number for page in pages for number in page] == list(range(total))
    assert http.get(url, params={"limit": SERIES_PAGE + 1}).status_code == 422


# --- free JSON fields -----------------------------------------------------------------


@pytest.mark.parametrize(
    ("fields", "named"),
    [
        ({"metadata": nested(MAX_JSON_DEPTH + 1)}, "metadata"),
        ({"metadata": nested(900)}, "metadata"),
        ({"metadata": {"notes": "x" * MAX_JSON_BYTES}}, "metadata"),
        ({"proposer": {"name": "random", "options": nested(300)}}, "proposer.options"),
        ({"task": EXTERNAL | {"options": nested(300)}, "max_trials": 5}, "task.options"),
        (
            {"task": EXTERNAL | {"options": {"k": ["v" * 1000] * 70}}, "max_trials": 5},
            "task.options",
        ),
    ],
)
def test_free_json_past_the_limits_is_422_naming_the_field(
    http: httpx.Client, fields: dict[str, Any], named: str
) -> None:
    assert refused_study(http, fields).startswith(f"{named}: ")


def test_free_json_at_the_limits_is_stored(http: httpx.Client) -> None:
    before = len(http.get("/api/v1/studies").json())
    deepest = nested(MAX_JSON_DEPTH)
    study = create(http, metadata={"deep": nested(MAX_JSON_DEPTH - 1)})
    assert depth_of(study["metadata"]) == depth_of(deepest)
    external = create(http, task=EXTERNAL | {"options": deepest}, max_trials=2)
    assert external["task"]["options"] == deepest
    assert len(http.get("/api/v1/studies").json()) == before + 2


def test_a_body_nested_past_the_parser_is_refused_not_a_500(http: httpx.Client) -> None:
    """A 422 naming the nesting, for a new study's metadata and a study's user attributes."""
    study = create(http)
    levels = 200_000  # 400 kB, under the body limit; json.loads gives up long before
    deep = "[" * levels + "]" * levels
    for method, path, body in (
        ("POST", "/api/v1/studies", '{"name": "deep", "metadata": {"a": ' + deep + "}}"),
        ("PATCH", f"/api/v1/studies/{study['id']}", '{"user_attrs": {"a": ' + deep + "}}"),
    ):
        response = http.request(
            method, path, content=body, headers={"Content-Type": "application/json"}
        )
        assert response.status_code == 422, response.text
        assert response.json()["detail"].startswith("body: objects and arrays nest deeper")
    assert http.get(f"/api/v1/studies/{study['id']}").json()["user_attrs"] == {}


BIG = 2**63
"""The first integer past 64 bits: a free JSON field refuses it (a browser reads an
integer past the float range as Infinity, and other languages' JSON readers stop at 64
bits)."""


@pytest.mark.parametrize(
    ("fields", "named"),
    [
        ({"metadata": {"n": BIG}}, "metadata.n"),
        ({"metadata": {"n": [1, -BIG - 1]}}, "metadata.n[1]"),
        ({"metadata": {"n": 10**400}}, "metadata.n"),
        ({"proposer": {"name": "random", "options": {"k": BIG}}}, "options.k"),
    ],
)
def test_free_json_integers_past_64_bits_are_422_naming_the_field(
    http: httpx.Client, fields: dict[str, Any], named: str
) -> None:
    assert f"{named}: integers must fit in 64 bits" in refused_study(http, fields)
    study = create(http, metadata={"low": -BIG, "high": BIG - 1})
    assert study["metadata"] == {"low": -BIG, "high": BIG - 1}
    patched = http.patch(f"/api/v1/studies/{study['id']}", json={"user_attrs": {"n": BIG}})
    assert patched.status_code == 422, patched.text
    assert "user_attrs.n: integers must fit in 64 bits" in patched.json()["detail"]
    assert http.get(f"/api/v1/studies/{study['id']}").json()["user_attrs"] == {}


@pytest.mark.parametrize(
    ("path", "body", "named"),
    [
        ("studies", STUDY | {"max_trials": True}, "max_trials"),
        ("studies", STUDY | {"max_trials": "5"}, "max_trials"),
        ("studies", STUDY | {"max_trials": 5.5}, "max_trials"),
        ("studies", STUDY | {"proposer": {"name": "random", "seed": "1"}}, "proposer.seed"),
        (
            "studies",
            STUDY | {"space": {**BOX, "params": [{"name": "x", "low": "0", "high": 1}]}},
            "space",
        ),
        (
            "studies",
            STUDY | {"pruner": {"name": "median", "options": {"n_startup_trials": "5"}}},
            "pruner",
        ),
        (
            "studies",
            STUDY | {"pruner": {"name": "median", "report_every": True}},
            "pruner.report_every",
        ),
        (
            "studies",
            STUDY | {"constraints": [{"metric": "m", "op": "<=", "bound": "2.5"}]},
            "constraints.0.bound",
        ),
        ("ask", {"count": "5"}, "count"),
        ("ask", {"count": True}, "count"),
        ("tell", {"value": "0.5"}, "value"),
        ("tell", {"value": True}, "value"),
        ("enqueue", {"params": {"x": 0.5}, "skip_if_exists": "yes"}, "trial.skip_if_exists"),
    ],
)
def test_numbers_and_truth_values_are_taken_only_as_json_gives_them(
    http: httpx.Client, path: str, body: dict[str, Any], named: str
) -> None:
    """A quoted number, a truth value for a number or a fractional number for an
    integer is a 422 naming the field (pydantic's lax mode read "5" as 5 and true as 1,
    and stored them)."""
    study = create(http)
    url = {
        "studies": "/api/v1/studies",
        "ask": f"/api/v1/studies/{study['id']}/ask",
        "enqueue": f"/api/v1/studies/{study['id']}/trials",
    }.get(path)
    if path == "tell":
        asked = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 1})
        url = f"/api/v1/trials/{asked.json()['trials'][0]['id']}/tell"
    before = http.get(f"/api/v1/studies/{study['id']}/trials").json()
    n_studies = len(http.get("/api/v1/studies").json())
    response = http.post(str(url), json=body)
    assert response.status_code == 422, response.text
    assert response.json()["detail"].startswith(f"{named}"), response.text
    if path in ("ask", "tell"):  # the detail shows what came: text or a truth value
        (given,) = body.values()
        shown = f"the text {given!r}" if isinstance(given, str) else str(given).lower()
        assert response.json()["detail"].endswith(f"(got {shown})"), response.text
    assert http.get(f"/api/v1/studies/{study['id']}/trials").json() == before
    assert len(http.get("/api/v1/studies").json()) == n_studies


STAND_UP = yaml.safe_load(
    (Path(__file__).resolve().parents[2] / "examples" / "stand-up.yaml").read_text()
)


@pytest.mark.parametrize(
    ("proposer", "task", "named"),
    [
        ({"raw_samples": True}, {}, "proposer.options.raw_samples"),
        ({"raw_samples": "512"}, {}, "proposer.options.raw_samples"),
        ({"maxiter": 50.5}, {}, "proposer.options.maxiter"),
        ({}, {"episode_steps": "100"}, "episode_steps"),
        ({}, {"frame_skip": True}, "frame_skip"),
        ({}, {"init_noise": "0.1"}, "init_noise"),
    ],
)
def test_options_take_numbers_only_as_json_gives_them(
    http: httpx.Client, proposer: dict[str, Any], task: dict[str, Any], named: str
) -> None:
    """A new study's proposer and task options are checked with a body's strict types
    (their models read them laxly, as the options older studies stored must load); an
    integral number is an integer there too."""
    body = STAND_UP | {"proposer": {"name": "qei", "options": proposer}}
    body["task"] = STAND_UP["task"] | {"options": task}
    assert named in refused_study(http, body)
    taken = STAND_UP | {"proposer": {"name": "qei", "options": {"raw_samples": 512.0}}}
    taken["task"] = STAND_UP["task"] | {"options": {"frame_skip": 12.0, "init_noise": 0}}
    created = http.post("/api/v1/studies", json=taken)
    assert created.status_code == 201, created.text


def test_a_body_json_cannot_read_is_422_saying_why(http: httpx.Client) -> None:
    """A number longer than Python converts, and bytes that are not UTF-8, are a 422
    saying which (FastAPI answered 400 "There was an error parsing the body")."""
    study = create(http)
    for body, says in (
        (b'{"user_attrs": {"n": ' + b"9" * 5000 + b"}}", "body: a number has more digits"),
        (b'{"user_attrs": {"n": "caf\xe9"}}', "body: not UTF-8 text"),
    ):
        response = http.patch(
            f"/api/v1/studies/{study['id']}",
            content=body,
            headers={"Content-Type": "application/json"},
        )
        assert response.status_code == 422, response.text
        assert response.json()["detail"].startswith(says), response.text
    assert http.get(f"/api/v1/studies/{study['id']}").json()["user_attrs"] == {}


def test_a_stored_row_past_the_limits_cannot_break_a_listing(
    live_server: ServerProcess, own_http: httpx.Client
) -> None:
    """A study stored before the limits (written here straight into the database): every
    listing still answers, showing its free JSON cut at MAX_JSON_DEPTH."""
    create(own_http)
    engine = sa.create_engine(live_server.database_url)
    with Session(engine) as session, session.begin():
        row = StudyRow(
            name="old",
            direction="maximize",
            state="running",
            space=BOX,
            proposer={"name": "random", "options": nested(300)},
            task=EXTERNAL | {"options": nested(300)},
            max_trials=5,
            metadata_=nested(300),
        )
        session.add(row)
        session.flush()
        old_id = row.id
    engine.dispose()

    listed = own_http.get("/api/v1/studies")
    assert listed.status_code == 200, listed.text
    old = own_http.get(f"/api/v1/studies/{old_id}")
    assert old.status_code == 200, old.text
    for value in (old.json()["metadata"], old.json()["task"]["options"]):
        assert depth_of(value) == MAX_JSON_DEPTH
        assert CUT_JSON in old.text
    with Client(live_server.url) as client:
        assert {study.name for study in client.studies()} == {"hostile", "old"}


def test_an_integer_an_older_server_stored_does_not_block_other_user_attrs(
    live_server: ServerProcess, own_http: httpx.Client
) -> None:
    """User attributes stored before the 64-bit rule (written here straight into the
    database) stay, and setting another key still works: the merge checks the changes'
    values, not those stored."""
    study = create(own_http)
    engine = sa.create_engine(live_server.database_url)
    with Session(engine) as session, session.begin():
        row = session.get(StudyRow, study["id"])
        assert row is not None
        row.user_attrs = {"big": 2**70}
    engine.dispose()
    url = f"/api/v1/studies/{study['id']}"
    patched = own_http.patch(url, json={"user_attrs": {"other": 1}})
    assert patched.status_code == 200, patched.text
    assert patched.json()["user_attrs"] == {"big": 2**70, "other": 1}
    refused = own_http.patch(url, json={"user_attrs": {"other": 2**64}})
    assert refused.status_code == 422, refused.text
    assert own_http.get(url).json()["user_attrs"] == {"big": 2**70, "other": 1}


def test_options_an_older_server_stored_laxly_still_load_and_ask(
    live_server: ServerProcess, own_http: httpx.Client
) -> None:
    """Proposer options stored before the strict check (written here straight into the
    database: a quoted number, a truth value) are read as their model reads them: the
    study loads and its asks are the model's, not a failure."""
    study = create(own_http, proposer={"name": "qei", "n_initial": 1, "seed": 1})
    engine = sa.create_engine(live_server.database_url)
    with Session(engine) as session, session.begin():
        row = session.get(StudyRow, study["id"])
        assert row is not None
        row.proposer = {**row.proposer, "options": {"raw_samples": "64", "warm_start": 1}}
    engine.dispose()
    url = f"/api/v1/studies/{study['id']}"
    for _ in range(3):
        asked = own_http.post(f"{url}/ask", json={"count": 1})
        assert asked.status_code == 200, asked.text
        (trial,) = asked.json()["trials"]
        told = own_http.post(
            f"/api/v1/trials/{trial['id']}/tell", json={"value": trial["params"]["x"]}
        )
        assert told.status_code == 200, told.text
    last = own_http.get(f"/api/v1/trials/{trial['id']}").json()
    assert last["info"]["method"] != "sobol-fallback", last["info"]
    assert own_http.get(url).json()["proposal_failures"] == 0


# --- bodies ---------------------------------------------------------------------------


def chunked_post(server: ServerProcess, path: str, chunks: list[bytes]) -> tuple[int, bytes]:
    """POST ``chunks`` with ``Transfer-Encoding: chunked`` (no Content-Length) over a
    raw socket; the answer's status and body."""
    head = (
        f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1:{server.port}\r\n"
        "Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n"
    ).encode()
    body = b"".join(b"%x\r\n%s\r\n" % (len(chunk), chunk) for chunk in chunks) + b"0\r\n\r\n"
    with socket.create_connection(("127.0.0.1", server.port), timeout=30) as sock:
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):
            sock.sendall(head + body)  # the server may answer and close before the end
        answer = b""
        while b"\r\n\r\n" not in answer or not _complete(answer):
            data = sock.recv(65536)
            if not data:
                break
            answer += data
    status = int(answer.split(b" ", 2)[1])
    return status, answer.split(b"\r\n\r\n", 1)[1]


def _complete(answer: bytes) -> bool:
    head, _, body = answer.partition(b"\r\n\r\n")
    length = re.search(rb"(?im)^content-length: *(\d+)", head)
    return length is not None and len(body) >= int(length.group(1))


def test_a_chunked_body_over_the_limit_is_413(server_factory: Callable[..., ServerProcess]) -> None:
    server = server_factory(AD_MAX_BODY_BYTES="2000")
    padding = b'{"name": "big", "metadata": {"pad": "' + b"x" * 1500
    status, body = chunked_post(server, "/api/v1/studies", [padding, b"x" * 1500, b'"}}'])
    assert status == 413, body
    assert b"too_large" in body and b"2000" in body
    small = [
        b'{"name": "small", "space": {"type": "box", "params": ',
        b'[{"name": "x", "low": 0, "high": 1}]}, "proposer": {"name": "random"}}',
    ]
    status, body = chunked_post(server, "/api/v1/studies", small)
    assert status == 201, body


# --- docs -----------------------------------------------------------------------------


@pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True)
@pytest.mark.parametrize("page", ["/docs", "/redoc"])
def test_docs_pages_load_only_files_the_server_serves(http: httpx.Client, page: str) -> None:
    response = http.get(page)
    assert response.status_code == 200
    html = response.text
    assert not re.search(r"(?i)(https?:)?//", html), html  # no URL outside the server
    assert "<script>" not in html  # none inline: the CSP allows script files only
    referenced = re.findall(r'(?:src|href)="([^"]+)"', html)
    assert any(url.endswith(".js") for url in referenced)
    for url in referenced:
        served = http.get(url)
        assert served.status_code == 200 and served.content, url
    assert http.get(re.findall(r'data-openapi="([^"]+)"', html)[0]).json()["openapi"]
