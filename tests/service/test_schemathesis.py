"""Property-based fuzzing of the whole HTTP API from its own OpenAPI document.

Schemathesis generates valid and invalid requests for every operation; each must get
a documented answer that matches its schema, and never a 5xx.

One check is left out: "a schema-valid request must be accepted". Some rules cannot be
written in JSON Schema (a param's low below its high, a structure that is a tree, a
study full at max_trials, a value for the id that exists), and those requests are
rightly refused with a 4xx naming the field; every other check runs.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.config import SchemathesisConfig
from schemathesis.specs.openapi.checks import positive_data_acceptance
from schemathesis.transport.requests import ManagedCookiesSession

from adclient.testing.servers import SDK_HEADERS, ServerProcess
from adservice.app import create_app
from adservice.settings import Settings

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


@pytest.fixture(scope="module")
def fuzzed_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    workdir = tmp_path_factory.mktemp("fuzz")
    server = ServerProcess(database_url=f"sqlite:///{workdir / 'fuzz.db'}", workdir=workdir)
    server.start()
    yield server
    server.stop()


@pytest.fixture(scope="module")
def fuzzing_session() -> Iterator[ManagedCookiesSession]:
    """One HTTP session for every case, as schemathesis's own runner keeps, each case
    sent as by a new client: the cookies a response sets are dropped before the next
    case and every case has a connection of its own (``Connection: close``; a kept-alive
    one cost the server more than the connects it saved). The server is on loopback: no
    proxy or netrc from the environment applies (``trust_env`` off)."""
    with ManagedCookiesSession() as session:
        session.trust_env = False
        yield session


# A request the schema forbids must be refused with a 4xx: schemathesis's list, plus 413
# (a body past the limit) and 431 (a query string past AD_MAX_HEADER_BYTES), which the
# server's protocol layer answers before any route sees the request.
REJECTIONS = [400, 401, 403, 404, 405, 406, 409, 413, 415, 422, 428, 429, 431]
CONFIG = SchemathesisConfig.from_dict(
    {"checks": {"negative_data_rejection": {"expected-statuses": REJECTIONS}}}
)


@pytest.fixture(scope="module")
def published_schema() -> schemathesis.schemas.BaseSchema:
    """The document the server publishes; the app is only built here (not started) to
    read it. Loaded by the test process that runs the test, not at collection: building
    the cases costs about 10 CPU-s, which every test process would pay otherwise."""
    return schemathesis.openapi.from_dict(
        create_app(Settings(database_url="sqlite://")).openapi(), config=CONFIG
    )


schema = schemathesis.pytest.from_fixture("published_schema")


@pytest.fixture(autouse=True)
def node_id_for_schemathesis(request: pytest.FixtureRequest) -> None:
    """schemathesis's lazy loader renames the test per operation through the node's
    ``_nodeid``, which pytest 9 no longer has: give it one to read and rewrite."""
    request.node._nodeid = request.node.nodeid


@schema.parametrize()
@settings(
    max_examples=30,
    deadline=None,
    suppress_health_check=list(HealthCheck),
    derandomize=True,
)
def test_every_operation_answers_within_its_schema(
    case: schemathesis.Case, fuzzed_server: ServerProcess, fuzzing_session: ManagedCookiesSession
) -> None:
    case.call_and_validate(
        base_url=fuzzed_server.url,
        session=fuzzing_session,
        headers={**SDK_HEADERS, "Connection": "close"},
        excluded_checks=[positive_data_acceptance],
    )
