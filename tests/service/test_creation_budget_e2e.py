"""Issue 58, finding 1: a design study's creation cannot freeze the server. Real
``adserver`` processes on SQLite files, auth on, plain ``user`` tokens.

Before, a creation computed its representation on a request thread with no budget: the
issue's 200 random 32-link trees took 198 s, abandoned creations went on computing, 41
of them stopped every read, and SIGTERM did not end the server. Now (adservice.creations)
a space whose similarity could not fit in ``AD_CREATE_SECONDS`` is refused at once, the
rest is computed in a child killed at its budget, when its client leaves or the server
stops, and a full pool answers 503. What is checked is the order of events, the answers
and the processes left, never a duration; ``PATIENCE`` only stops a broken build from
hanging.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import select
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import httpx
import pytest

from adclient.testing import isolation
from adclient.testing.servers import SDK_HEADERS, ServerProcess, make_token
from adclient.testing.workers import wait_for

pytestmark = pytest.mark.e2e

PATIENCE = 60.0
LONG = "600"
"""AD_CREATE_SECONDS that lets the issue's space through, so that its child computes for
minutes (its similarity alone, about 1e8 steps, takes a minute or more here)."""


def random_trees_space(count: int, links: int, seed: int) -> dict[str, Any]:
    """``count`` distinct random trees of ``links`` links, as the issue's tester made."""
    rng = random.Random(seed)
    names = [f"l{i}" for i in range(links)]
    trees: list[list[list[str]]] = []
    seen: set[frozenset[tuple[str, str]]] = set()
    while len(trees) < count:
        edges = [(names[rng.randrange(i)], names[i]) for i in range(1, links)]
        if frozenset(edges) not in seen:
            seen.add(frozenset(edges))
            trees.append([list(edge) for edge in edges])
    link = {"length": {"low": 0.1, "high": 0.5}, "radius": 0.04, "mass": 1.0}
    return {
        "type": "design",
        "parts": {"link": link},
        "instances": [{"name": name, "part": "link"} for name in names],
        "structures": trees,
        "max_structures": 1000,
        # a creation's cost is the point, not the robots: siblings at rest lie along one
        # line, through each other, and the overlap check would refuse the space at once
        "allow_overlaps": True,
    }


def study(space: dict[str, Any], name: str = "s") -> dict[str, Any]:
    return {"name": name, "space": space, "proposer": {"name": "random"}}


ISSUE_SPACE = random_trees_space(200, 32, seed=1)
SMALL_SPACE: dict[str, Any] = {
    "type": "design",
    "parts": {"link": {"length": {"low": 0.1, "high": 0.5}, "radius": 0.04, "mass": 1.0}},
    "instances": [{"name": name, "part": "link"} for name in "abc"],
    "structures": [[["a", "b"], ["b", "c"]], [["a", "b"], ["a", "c"]]],
}
BOX = {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]}
HEAVY_FUSION = SMALL_SPACE | {
    "reference_per_structure": 256,
    "parts": {"link": SMALL_SPACE["parts"]["link"] | {"radius": {"low": 0.02, "high": 0.1}}},
}
"""Two structures (their similarity is nothing) of 256 reference designs each: a fusion of
130,816 pairs (about 0.8 s and 60 MB here)."""


@pytest.fixture
def start_server(
    tmp_path_factory: pytest.TempPathFactory, new_sqlite_url: Callable[[], str]
) -> Iterator[Callable[..., ServerProcess]]:
    """Start real servers with auth on: ``start_server(AD_CREATE_SECONDS="2")``."""
    started: list[ServerProcess] = []

    def start(database_url: str | None = None, **env: str) -> ServerProcess:
        server = ServerProcess(
            database_url=database_url or new_sqlite_url(),
            workdir=tmp_path_factory.mktemp("creations"),
            env={"AD_AUTH": "1", **env},
        )
        started.append(server.start())
        return server

    yield start
    for server in started:
        server.kill()


def user(server: ServerProcess, name: str, timeout: float = PATIENCE) -> httpx.Client:
    token = make_token(server, "user", name=name)
    return httpx.Client(
        base_url=server.url,
        headers={**SDK_HEADERS, "Authorization": f"Bearer {token}"},
        timeout=timeout,
        verify=False,
        limits=httpx.Limits(max_connections=None),
    )


def _parents() -> dict[int, int]:
    parents = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as stat:
                    parents[int(entry)] = int(stat.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue  # ended meanwhile
    return parents


def creation_children(server: ServerProcess) -> set[int]:
    """The processes computing creations: the children of the server's helper (the
    server's children's children)."""
    assert server.process is not None
    parents = _parents()
    helpers = {pid for pid, parent in parents.items() if parent == server.process.pid}
    return {pid for pid, parent in parents.items() if parent in helpers and _alive(pid)}


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def names_stored(http: httpx.Client) -> list[str]:
    answer = http.get("/api/v1/studies")
    answer.raise_for_status()
    return sorted(row["name"] for row in answer.json())


def test_the_issues_creation_is_refused_at_once_naming_its_budget(
    start_server: Callable[..., ServerProcess],
) -> None:
    server = start_server()
    with user(server, "alice") as alice:
        answer = alice.post("/api/v1/studies", json=study(ISSUE_SPACE, "freeze"))
        assert answer.status_code == 422, answer.text
        detail = answer.json()["detail"]
        assert "space.structures" in detail and "AD_CREATE_SECONDS" in detail, detail
        assert "200 structures" in detail and "30 s" in detail, detail
        assert names_stored(alice) == []
        assert creation_children(server) == set()  # refused before any child
        # a space within the budget is created
        created = alice.post("/api/v1/studies", json=study(SMALL_SPACE, "small"))
        assert created.status_code == 201, created.text
        assert names_stored(alice) == ["small"]


def test_a_creation_past_its_time_is_killed_with_a_422_naming_it_and_stores_nothing(
    start_server: Callable[..., ServerProcess],
) -> None:
    # timed on a server with the default budget, then given a fifth of what it took
    heavy = HEAVY_FUSION
    with user(start_server(), "alice") as alice:
        assert alice.post("/api/v1/studies", json=study(SMALL_SPACE)).status_code == 201
        started = time.monotonic()
        created = alice.post("/api/v1/studies", json=study(heavy, "measured"))
        took = time.monotonic() - started
        assert created.status_code == 201, created.text
    budget = f"{took / 5:.3g}"
    server = start_server(AD_CREATE_SECONDS=budget)
    with user(server, "alice") as alice:
        answer = alice.post("/api/v1/studies", json=study(heavy, "heavy"))
        assert answer.status_code == 422, answer.text
        detail = answer.json()["detail"]
        assert f"limit of {float(budget):g} s (AD_CREATE_SECONDS)" in detail, detail
        assert "nothing was stored" in detail, detail
        assert names_stored(alice) == []
        wait_for(lambda: creation_children(server) == set(), "the killed child to end")


def test_a_creation_past_its_memory_is_a_422_naming_it_and_stores_nothing(
    start_server: Callable[..., ServerProcess],
) -> None:
    server = start_server(AD_CREATE_MEMORY_MB="20")
    with user(server, "alice") as alice:
        answer = alice.post("/api/v1/studies", json=study(HEAVY_FUSION, "heavy"))
        assert answer.status_code == 422, answer.text
        detail = answer.json()["detail"]
        assert "limit of 20 MB (AD_CREATE_MEMORY_MB)" in detail, detail
        assert names_stored(alice) == []
        created = alice.post("/api/v1/studies", json=study(SMALL_SPACE, "small"))
        assert created.status_code == 201, created.text  # the next child has its own


def test_a_full_pool_answers_503_and_abandoned_creations_end_while_others_are_served(
    start_server: Callable[..., ServerProcess],
) -> None:
    server = start_server(AD_CREATE_SECONDS=LONG, AD_CREATE_PROCESSES="2", AD_CREATE_QUEUE="1")
    alice, carol, dave = (
        make_token(server, "user", name=name) for name in ("alice", "carol", "dave")
    )
    with user(server, "bob") as bob:
        ordinary = bob.post("/api/v1/studies", json=study(BOX, "ordinary")).json()["id"]
        # two owners' creations compute (one owner's run on one process at most)
        computing = [send_creation(server, token, seed) for token, seed in ((alice, 1), (carol, 2))]
        children = wait_for(
            lambda: len(creation_children(server)) == 2 and creation_children(server),
            "two creations computing",
        )
        # two more: one waits for a place, the other finds none and is answered at once
        waiting = send_creation(server, alice, 3)
        wait_for(lambda: pool_places(bob, "waiting") == 1, "alice's third to wait for her turn")
        assert pool_places(bob, "running") == 2
        full = send_creation(server, dave, 4)
        answered, _, _ = select.select([waiting, full], [], [], PATIENCE)
        assert answered == [full], answered
        reply = full.recv(65_536).decode()
        assert reply.startswith("HTTP/1.1 503 "), reply
        assert "\r\nretry-after: 5\r\n" in reply.lower(), reply
        assert "AD_CREATE_PROCESSES" in reply and "AD_CREATE_QUEUE" in reply, reply
        # the other user is served meanwhile: reads, /healthz, a new study
        for _ in range(5):
            assert bob.get(f"/api/v1/studies/{ordinary}").status_code == 200
            assert bob.get("/healthz").status_code == 200
        assert bob.post("/api/v1/studies", json=study(BOX, "another")).status_code == 201
        assert creation_children(server) == children  # still computing all along
        # their clients go: the children are killed (before: the work went on)
        for sock in [*computing, waiting, full]:
            sock.close()
        wait_for(lambda: creation_children(server) == set(), "the abandoned children to end")
        assert bob.post("/api/v1/studies", json=study(SMALL_SPACE, "small")).status_code == 201
        assert names_stored(bob) == ["another", "ordinary", "small"]


def test_one_owners_creations_keep_to_their_share_and_others_are_served_at_once(
    start_server: Callable[..., ServerProcess],
) -> None:
    """An owner holds at most ``AD_CREATE_PER_OWNER`` places (then 429 naming it) and runs
    on all but one process, so another owner's creation is computed while its are."""
    server = start_server(
        AD_CREATE_SECONDS=LONG,
        AD_CREATE_PROCESSES="2",
        AD_CREATE_QUEUE="8",
        AD_CREATE_PER_OWNER="2",
    )
    alice = make_token(server, "user", name="alice")
    with user(server, "bob") as bob:
        held = [send_creation(server, alice, seed) for seed in (1, 2)]
        (child,) = wait_for(lambda: creation_children(server), "alice's first creation computing")
        refused = send_creation(server, alice, 3)
        reply = refused.recv(65_536).decode()
        assert reply.startswith("HTTP/1.1 429 "), reply
        assert "already has 2 study creations running or waiting (AD_CREATE_PER_OWNER)" in reply
        # bob's creation does not wait behind alice's: it is computed beside her first
        assert bob.post("/api/v1/studies", json=study(SMALL_SPACE, "small")).status_code == 201
        assert child in creation_children(server), "alice's first stopped computing"
        # bob's child may still be ending after its answer; alice's second never starts
        deadline = time.monotonic() + PATIENCE
        while creation_children(server) != {child} and time.monotonic() < deadline:
            time.sleep(0.05)
        assert creation_children(server) == {child}, "another of alice's is computing"
        answered, _, _ = select.select(held, [], [], 0)
        assert answered == [], "an of alice's creations was answered"
        for sock in [*held, refused]:
            sock.close()
        wait_for(lambda: creation_children(server) == set(), "the abandoned children to end")
        assert names_stored(bob) == ["small"]


def pool_places(http: httpx.Client, state: str) -> float:
    """The creation pool's places ``running`` or ``waiting`` (/metrics)."""
    text = http.get("/metrics").text
    line = f'activedesign_pool_places{{pool="creations",state="{state}"}} '
    (value,) = [row.removeprefix(line) for row in text.splitlines() if row.startswith(line)]
    return float(value)


def send_creation(server: ServerProcess, token: str, seed: int) -> socket.socket:
    """A connection that has sent a creation of the issue's space (its answer unread)."""
    body = json.dumps(study(random_trees_space(200, 32, seed=seed), f"freeze {seed}")).encode()
    head = (
        f"POST /api/v1/studies HTTP/1.1\r\nHost: 127.0.0.1:{server.port}\r\n"
        f"Authorization: Bearer {token}\r\nContent-Type: application/json\r\n"
        f"X-Activedesign-Client: test\r\nContent-Length: {len(body)}\r\n\r\n"
    )
    sock = socket.create_connection(("127.0.0.1", server.port))
    sock.settimeout(PATIENCE)
    sock.sendall(head.encode() + body)
    return sock


def busy_seconds(server: ServerProcess) -> float:
    """The CPU seconds the server and every process below it have used, live ones only."""
    assert server.process is not None
    parents = _parents()
    tree, grown = {server.process.pid}, True
    while grown:
        below = {pid for pid, parent in parents.items() if parent in tree} - tree
        tree |= below
        grown = bool(below)
    total = 0
    for pid in tree:
        try:
            with open(f"/proc/{pid}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()
            total += int(fields[11]) + int(fields[12])
        except (OSError, IndexError, ValueError):
            continue
    return total / os.sysconf("SC_CLK_TCK")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_ends_the_server_within_its_shutdown_time_with_a_creation_in_flight(
    start_server: Callable[..., ServerProcess], new_sqlite_url: Callable[[], str], sig: int
) -> None:
    # the stated time 2 s: the creation's request gets 1.5 s, then is cancelled
    url = new_sqlite_url()
    server = start_server(url, AD_CREATE_SECONDS=LONG, AD_SHUTDOWN_SECONDS="2")
    assert server.process is not None
    with user(server, "alice") as alice:
        answers: list[Any] = []

        def create() -> None:
            try:
                answers.append(alice.post("/api/v1/studies", json=study(ISSUE_SPACE)))
            except httpx.TransportError as error:
                answers.append(error)

        idle = busy_seconds(server)
        sender = threading.Thread(target=create)
        sender.start()
        # the creation computing (in a child now, in a request thread before)
        wait_for(lambda: busy_seconds(server) > idle + 1.0, "the creation computing")
        children = creation_children(server)
        signalled = time.monotonic()
        server.process.send_signal(sig)
        try:
            server.process.wait(timeout=PATIENCE)  # before: the creation's 198 s, then more
        except subprocess.TimeoutExpired:
            pytest.fail(f"adserver still running {PATIENCE} s after {sig!r}")
        ended = time.monotonic() - signalled
        sender.join()
    log = server.log()
    assert "exiting now" not in log, log  # ended by the bound on requests, not the last resort
    assert ended >= 1.0, ended  # it gave the request its time first
    wait_for(lambda: not any(_alive(pid) for pid in children), "the creation's child to end")
    (answer,) = answers
    assert not isinstance(answer, httpx.Response) or answer.status_code != 201, answer
    restarted = start_server(url)
    with user(restarted, "bob") as bob:
        assert names_stored(bob) == []  # nothing half-stored


@pytest.mark.slow
def test_sigterm_ends_the_server_within_its_shutdown_time_with_an_ask_computing(
    start_server: Callable[..., ServerProcess],
) -> None:
    # an ask's search runs in a thread nothing can cancel: the last resort ends the process
    server = start_server(AD_ASK_SECONDS=LONG, AD_SHUTDOWN_SECONDS="2")
    assert server.process is not None
    with user(server, "alice") as alice:
        heavy = isolation.heavy_study(
            alice, "heavy", 96, 40, 32, {"raw_samples": 16384, "num_restarts": 128}
        )
        idle = busy_seconds(server)
        asking = threading.Thread(target=_ask, args=(alice, heavy))
        asking.start()
        wait_for(lambda: busy_seconds(server) > idle + 1.0, "the ask computing")
        server.process.send_signal(signal.SIGTERM)
        try:
            server.process.wait(timeout=PATIENCE)  # before: once the ask's thread ended
        except subprocess.TimeoutExpired:
            pytest.fail(f"adserver still running {PATIENCE} s after SIGTERM")
        asking.join()
    log = server.log()
    assert "still running 2 s after the signal to stop (AD_SHUTDOWN_SECONDS)" in log, log
    assert server.process.returncode == 1


def _ask(http: httpx.Client, study_id: int) -> None:
    with contextlib.suppress(httpx.TransportError):
        http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 32})
