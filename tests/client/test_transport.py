"""The SDK's error mapping and retries, against a real HTTP server answering from a script."""

from __future__ import annotations

import json
import pickle
from collections.abc import Iterator
from typing import Any

import pytest

from adclient import (
    ActiveDesignError,
    ApiError,
    Client,
    Conflict,
    Forbidden,
    Invalid,
    NotFound,
    PayloadTooLarge,
    Unauthorized,
    Unavailable,
)
from tests.client.scripted_server import HangUp, Reply, ScriptedServer, refused_url

NOW = "2025-01-01T00:00:00Z"


def trial_body(trial_id: int = 1, **changes: object) -> dict[str, object]:
    body: dict[str, object] = {
        "id": trial_id,
        "study_id": 1,
        "number": trial_id - 1,
        "state": "running",
        "params": {"x": 0.5},
        "vector": [0.5],
        "value": None,
        "worker_id": None,
        "created_at": NOW,
    }
    body.update(changes)
    return body


@pytest.fixture
def scripted() -> Iterator[ScriptedServer]:
    server = ScriptedServer().start()
    yield server
    server.stop()


@pytest.fixture
def client(scripted: ScriptedServer) -> Iterator[Client]:
    with Client(scripted.url, retries=3, backoff=0.02, max_backoff=1.0) as api:
        yield api


@pytest.mark.parametrize(
    ("status", "cls"),
    [
        (400, Invalid),
        (401, Unauthorized),
        (403, Forbidden),
        (404, NotFound),
        (409, Conflict),
        (413, PayloadTooLarge),
        (422, Invalid),
    ],
)
def test_error_status_maps_to_its_class_with_code_and_detail(
    scripted: ScriptedServer, client: Client, status: int, cls: type[ApiError]
) -> None:
    scripted.play(Reply(status, {"error": "some_code", "detail": "study 7 not found"}))
    with pytest.raises(cls) as caught:
        client.study_info(7)
    error = caught.value
    assert error.status_code == status
    assert error.code == "some_code"
    assert error.detail == "study 7 not found"
    assert error.message == "study 7 not found"
    assert isinstance(error, ActiveDesignError)
    assert len(scripted.seen) == 1, "a 4xx answer is final: no retry"
    assert scripted.seen[0].path == "/api/v1/studies/7"


def test_unlisted_4xx_is_a_plain_api_error(scripted: ScriptedServer, client: Client) -> None:
    scripted.play(Reply(418, {"error": "teapot", "detail": "short and stout"}))
    with pytest.raises(ApiError) as caught:
        client.studies()
    assert type(caught.value) is ApiError
    assert caught.value.status_code == 418
    assert len(scripted.seen) == 1


def test_fastapi_validation_detail_is_flattened_to_one_line(
    scripted: ScriptedServer, client: Client
) -> None:
    detail = [
        {"loc": ["body", "count"], "msg": "Input should be less than or equal to 64"},
        {"loc": ["body", "name"], "msg": "Field\nrequired"},
    ]
    scripted.play(Reply(422, {"error": "invalid", "detail": detail}))
    with pytest.raises(Invalid) as caught:
        client.ask(1, 65)
    assert caught.value.message == (
        "body.count: Input should be less than or equal to 64; body.name: Field required"
    )
    assert isinstance(caught.value, ValueError)


def test_error_without_json_body_keeps_the_text(scripted: ScriptedServer, client: Client) -> None:
    scripted.play(Reply(404, raw=b"no such page", headers={"Content-Type": "text/plain"}))
    with pytest.raises(NotFound) as caught:
        client.studies()
    assert caught.value.code == "not_found"
    assert caught.value.message == "no such page"


def test_503_twice_then_200_succeeds_after_growing_waits(
    scripted: ScriptedServer, client: Client
) -> None:
    busy = Reply(503, {"error": "unavailable", "detail": "database busy"})
    scripted.play(busy, busy, Reply(200, [trial_body(1), trial_body(2)]))
    # a GET that lists trials: retried on 5xx
    trials = client.trials(1)
    assert [trial.id for trial in trials] == [1, 2]
    assert len(scripted.seen) == 3
    gaps = [b.at - a.at for a, b in zip(scripted.seen, scripted.seen[1:], strict=False)]
    # equal jitter: wait n lies in [backoff * 2**n / 2, backoff * 2**n]
    assert gaps[0] >= 0.02 / 2
    assert gaps[1] >= 0.04 / 2


def test_5xx_on_post_is_retried_because_the_server_rolled_it_back(
    scripted: ScriptedServer, client: Client
) -> None:
    scripted.play(Reply(500, {"error": "internal", "detail": "boom"}), Reply(200, {"trials": []}))
    assert client.ask(1, 1) == []
    assert [seen.method for seen in scripted.seen] == ["POST", "POST"]
    assert json.loads(scripted.seen[1].body) == {"count": 1}


def test_persistent_503_raises_unavailable_after_all_retries(
    scripted: ScriptedServer, client: Client
) -> None:
    scripted.play(Reply(503, {"error": "unavailable", "detail": "down for maintenance"}))
    with pytest.raises(Unavailable) as caught:
        client.studies()
    assert caught.value.status_code == 503
    assert caught.value.message == "down for maintenance"
    assert len(scripted.seen) == 1 + client.retries


def test_retry_after_header_sets_the_wait(scripted: ScriptedServer) -> None:
    with Client(scripted.url, retries=1, backoff=0.001, max_backoff=5.0) as api:
        scripted.play(
            Reply(503, {"error": "unavailable", "detail": "busy"}, {"Retry-After": "0.3"}),
            Reply(200, []),
        )
        assert api.studies() == []
    assert scripted.seen[1].at - scripted.seen[0].at >= 0.3


def test_zero_retries_means_one_attempt(scripted: ScriptedServer) -> None:
    with Client(scripted.url, retries=0) as api:
        scripted.play(Reply(503, {"error": "unavailable", "detail": "busy"}))
        with pytest.raises(Unavailable):
            api.studies()
    assert len(scripted.seen) == 1


def test_dropped_connection_on_a_read_is_retried(scripted: ScriptedServer, client: Client) -> None:
    scripted.play(HangUp(), Reply(200, []))
    assert client.studies() == []
    assert len(scripted.seen) == 2


def test_dropped_connection_on_a_tell_is_retried(scripted: ScriptedServer, client: Client) -> None:
    """A repeated identical tell is harmless on the server, so a lost answer is retried."""
    scripted.play(HangUp(), Reply(200, trial_body(3, state="complete", value=1.5)))
    trial = client.tell(3, 1.5)
    assert trial.value == 1.5
    assert len(scripted.seen) == 2
    assert scripted.seen[0].body == scripted.seen[1].body
    assert json.loads(scripted.seen[1].body) == {"value": 1.5, "state": "complete", "metrics": {}}


@pytest.mark.parametrize("call", ["ask", "create_study", "lease"])
def test_dropped_connection_on_a_creating_request_is_not_repeated(
    scripted: ScriptedServer, client: Client, call: str
) -> None:
    scripted.play(HangUp(), Reply(200, {"trials": []}))
    with pytest.raises(Unavailable) as caught:
        if call == "ask":
            client.ask(1, 2)
        elif call == "create_study":
            client.create_study(name="s", space={"type": "box", "params": []})
        else:
            client.lease("w1")
    assert caught.value.status_code is None
    assert caught.value.code == "no_answer"
    assert len(scripted.seen) == 1, "sent once only: a second send could create twice"


def test_connection_refused_is_unavailable_after_retries() -> None:
    url = refused_url()
    with Client(url, retries=2, backoff=0.01) as api, pytest.raises(Unavailable) as caught:
        api.studies()
    assert caught.value.status_code is None
    assert caught.value.code == "unreachable"
    assert f"cannot reach server at {url}" in str(caught.value)


def test_bearer_token_is_sent_only_when_given(scripted: ScriptedServer) -> None:
    scripted.play(Reply(200, []))
    with Client(scripted.url, token="s3cret") as api:
        api.studies()
    with Client(scripted.url) as api:
        api.studies()
    assert scripted.seen[0].headers.get("Authorization") == "Bearer s3cret"
    assert "Authorization" not in scripted.seen[1].headers


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"value": float("nan")}, "finite"),
        ({"value": float("inf")}, "finite"),
        ({"value": 1.0, "metrics": {"reward": float("nan")}}, "finite"),
        ({"value": None, "state": "complete"}, "value is required"),
        ({"value": 2.0, "state": "failed"}, "no value"),
        ({"value": None, "state": "running"}, "state"),
    ],
)
def test_bad_tell_is_refused_before_sending(
    scripted: ScriptedServer, client: Client, kwargs: dict[str, object], fragment: str
) -> None:
    with pytest.raises(Invalid) as caught:
        client.tell(1, **kwargs)  # type: ignore[arg-type, unused-ignore]
    assert fragment in caught.value.message
    assert caught.value.status_code is None
    assert scripted.seen == []


def test_tell_without_value_is_a_failure_report(scripted: ScriptedServer, client: Client) -> None:
    scripted.play(Reply(200, trial_body(4, state="failed", message="diverged")))
    trial = client.tell(4, message="diverged", worker_id="w1")
    assert trial.state == "failed"
    assert json.loads(scripted.seen[0].body) == {
        "state": "failed",
        "message": "diverged",
        "worker_id": "w1",
        "metrics": {},
    }


def test_lease_with_no_work_is_none(scripted: ScriptedServer, client: Client) -> None:
    scripted.play(Reply(204))
    assert client.lease("w1") is None
    assert json.loads(scripted.seen[0].body) == {"worker_id": "w1"}


def test_artifacts_travel_as_raw_bytes(scripted: ScriptedServer, client: Client) -> None:
    blob = bytes(range(256)) * 4
    scripted.play(
        Reply(
            200,
            {"name": "img.png", "size": len(blob), "content_type": "image/png", "created_at": NOW},
        ),
        Reply(200, raw=blob, headers={"Content-Type": "image/png"}),
    )
    info = client.put_artifact(5, "img.png", blob, "image/png")
    assert info is not None and info.size == len(blob)
    assert client.get_artifact(5, "img.png") == blob
    put, get = scripted.seen
    assert (put.method, put.path) == ("PUT", "/api/v1/trials/5/artifacts/img.png")
    assert put.body == blob
    assert put.headers["Content-Type"] == "image/png"
    assert (get.method, get.path) == ("GET", "/api/v1/trials/5/artifacts/img.png")


def test_study_handle_ask_shapes(scripted: ScriptedServer, client: Client) -> None:
    """ask() gives one Trial; ask(count=n) a list, even for n == 1."""
    from adclient.client import StudyHandle

    handle = StudyHandle(client, 1)
    scripted.play(Reply(200, {"trials": [trial_body(1)]}))
    single = handle.ask()
    assert single.id == 1
    listed = handle.ask(count=1)
    assert isinstance(listed, list) and [t.id for t in listed] == [1]
    assert [json.loads(seen.body) for seen in scripted.seen] == [{"count": 1}, {"count": 1}]


def test_api_errors_survive_pickling() -> None:
    error = Conflict(409, "lease_lost", "trial 3 is leased to w2", method="POST", url="/x")
    copy = pickle.loads(pickle.dumps(error))
    assert type(copy) is Conflict
    assert (copy.status_code, copy.code, copy.detail) == (409, "lease_lost", error.detail)
    assert str(copy) == str(error)


def test_trial_urdf_is_text(scripted: ScriptedServer, client: Client) -> None:
    urdf = '<?xml version="1.0"?>\n<robot name="r1"><link name="base"/></robot>\n'
    scripted.play(Reply(200, raw=urdf.encode(), headers={"Content-Type": "application/xml"}))
    assert client.trial_urdf(9) == urdf
    assert (scripted.seen[0].method, scripted.seen[0].path) == ("GET", "/api/v1/trials/9/urdf")


def _certificate_check(client: Client) -> Any:
    return client._http._transport._pool._ssl_context


def test_clients_of_one_process_share_one_certificate_check(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Loading a CA bundle costs about 30 ms of CPU: a process that makes many clients
    loads it once per ``verify`` setting and CA environment, and each check still
    verifies."""
    import ssl

    with Client("http://127.0.0.1:1") as first, Client("https://example.invalid") as second:
        shared = _certificate_check(first)
        assert shared is _certificate_check(second)
    assert isinstance(shared, ssl.SSLContext) and shared.verify_mode == ssl.CERT_REQUIRED
    with Client("http://127.0.0.1:1", verify=False) as unverified:
        assert _certificate_check(unverified) is not shared
        assert _certificate_check(unverified).verify_mode == ssl.CERT_NONE
    import certifi

    monkeypatch.setenv("SSL_CERT_FILE", certifi.where())  # another CA setting: its own check
    with Client("http://127.0.0.1:1") as other:
        assert _certificate_check(other) is not shared
